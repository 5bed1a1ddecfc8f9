// The soft-tissue part of the FEM soft skeleton (ARCHITECTURE.md §4), private to Simulable: the
// tet nodes' skinning, lumped masses, held pose blend offsets and displacements u, and the
// energies that involve the nodes (inertia, gravity, collider contact on the surface nodes,
// elasticity). The bones' own terms (joint and tracking springs) stay in simulable.cpp.
//
// Node j of the tet mesh is at x_j = Σ_b w_jb (R_b (Y_j − J_b) + t_b), Y_j = X̄_j + P_j + u_j
// (rest node, held pose blend offset, displacement; u = 0 on bone nodes). Its derivatives in the
// increment chart (δt_b, δω_b, δu_j):
//   ∂x_j/∂δt_b = w_jb I,  ∂x_j/∂δω_b = −w_jb [r_jb]×  with r_jb = R_b (Y_j − J_b),
//   ∂x_j/∂δu_j = M_j = Σ_b w_jb R_b.
// Second derivatives: ∂²(f·x_j)/∂δω_b² = w_jb (½(f r_jbᵀ + r_jb fᵀ) − (f·r_jb) I) and
// ∂²(f·x_j)/∂δω_b∂δu_j = −w_jb [f]× R_b.
#pragma once

#include <vector>

#include "flsh/contact/collider.h"
#include "flsh/contact/contact_energy.h"
#include "flsh/core/types.h"
#include "flsh/sim/fem_material.h"
#include "flsh/sim/skeleton_energies.h"
#include "flsh/volume/soft_avatar.h"
#include "hessian_blocks.h"

namespace flsh::detail {

/// Bone transforms a soft-tissue evaluation reads (borrowed).
struct BoneFrames {
  const std::vector<Mat3>& R;  ///< 24 rotations
  const MatX3& t;              ///< 24 × 3 joint positions, m
};

class SoftTissue {
 public:
  /// Reads the avatar's volumetric data (soft tissue on, initialized). `joints`: 24 × 3 rest
  /// joints J(β) (the simulable's).
  SoftTissue(const SoftAvatar& avatar, const MatX3& joints, const std::vector<int>& parents,
             double time_step);

  int numNodes() const { return int(rest_.rows()); }
  int numSurface() const { return num_surface_; }
  int numSoftDofs() const { return 3 * int(soft_nodes_.size()); }
  const VecXi& softNodes() const { return soft_nodes_; }
  /// Offset of node j's displacement in u (3 values), −1 for a bone node.
  int nodeDof(int j) const { return node_dof_[j]; }

  // ---- state (the bones live in Simulable) ----
  VecX u, u_n, u_nm1;  ///< 3 · #soft nodes each, m

  /// Held pose blend offsets P (#N × 3, m) from the bones' rotations (relative rotations
  /// R_pᵀ R_b give the pose feature).
  void setPoseBlend(const std::vector<Mat3>& R);
  const MatX3& poseBlend() const { return blend_; }
  void setPoseBlendOffsets(const MatX3& offsets) { blend_ = offsets; }

  /// Y = X̄ + P + u of every node (#N × 3) for a displacement vector.
  void unposed(const VecX& displacement, MatX3& Y) const;
  /// World positions x (#N × 3) of every node for bones and a displacement vector.
  void positions(const BoneFrames& bones, const VecX& displacement, MatX3& x) const;
  /// x̂ = 2 x(q_n) − x(q_{n−1}) with the held pose blend (it carries no momentum).
  void setPrediction(const BoneFrames& bones_n, const BoneFrames& bones_nm1);

  /// Evaluates the node positions of the current state (bones + u); cached by `version`.
  void prepare(long version, const BoneFrames& bones) const;
  const MatX3& currentPositions() const { return x_; }
  const MatX3& currentUnposed() const { return Y_; }

  // ---- energies at the prepared state; gradients ADDED at offset (bones at offset, u at
  // offset + bone_dofs), Hessian triplets APPENDED (both triangles) ----
  double inertia(VecX* g, std::vector<Triplet>* H, int offset, bool psd) const;
  double gravity(const Vec3& gravity, VecX* g, std::vector<Triplet>* H, int offset,
                 bool psd) const;
  double elastic(VecX* g, std::vector<Triplet>* H, int offset, bool psd) const;
  /// Penalty contact of the surface nodes against colliders at time t.
  double contact(const std::vector<Collider>& colliders, double time,
                 const ContactOptions& options, VecX* g, std::vector<Triplet>* H, int offset,
                 bool psd, int* active = nullptr) const;

  /// d(surface nodes)/dq rows (3#V × numDofs) as triplets.
  void surfaceJacobian(std::vector<Triplet>& triplets) const;

 private:
  struct Influence {
    int bone;
    double weight;
  };
  int num_bones_ = 0, num_surface_ = 0, bone_dofs_ = 0;
  double h_ = 0.0;
  MatX3 rest_;          // #N × 3, X̄(β)
  const MatX* posedirs_ = nullptr;  // 3#N × 207 (owned by the avatar's template)
  std::vector<int> parents_;
  MatX3 joints_;        // 24 × 3
  MatX3 blend_;         // #N × 3
  VecX mass_;           // #N
  VecXi soft_nodes_;
  std::vector<int> node_dof_;
  std::vector<int> influence_start_;
  std::vector<Influence> influences_;
  MatX3 x_hat_;
  VecX areas_;          // #V surface vertex areas, m²

  // Elements.
  MatX4i tets_;
  std::vector<TetElementRest> elements_;
  std::vector<FemMaterialPoint> materials_;
  // Ordered soft-node pairs (i, j) sharing a tet, one 3 × 3 block each; element e's local pair
  // (a, b) adds into block tet_block_[16 e + 4 a + b] (−1: a bone node).
  std::vector<std::pair<int, int>> block_pairs_;
  std::vector<int> tet_block_;

  // Caches of the prepared state.
  mutable long version_ = -1;
  mutable MatX3 x_, Y_;
  mutable std::vector<Mat3> node_M_;  // M_j = Σ_b w_jb R_b
  mutable std::vector<Vec12> element_gradients_;
  mutable std::vector<Mat12> element_hessians_;
  mutable std::vector<Mat3> blocks_;
  mutable BonePairBlocks pair_blocks_;
  // Bones of the prepared state (the simulable's, which outlive every evaluation).
  mutable const std::vector<Mat3>* cur_R_ = nullptr;
  mutable const MatX3* cur_t_ = nullptr;

  Eigen::Matrix<double, 3, 4> elementDisplacement(int e) const;
  Vec3 nodeDisplacement(const VecX& displacement, int j) const {
    return node_dof_[j] < 0 ? Vec3::Zero() : Vec3(displacement.segment<3>(node_dof_[j]));
  }
  /// Adds Σ_j J_jᵀ f_j (f: per-node ∂E/∂x_j for the listed nodes) into g.
  void mapForces(const std::vector<int>& nodes, const std::vector<Vec3>& forces, VecX& g,
                 int offset) const;
  /// Appends Σ_j J_jᵀ K_j J_j (K_j symmetric 3 × 3; null = none) plus, when `forces` is given,
  /// the curvature of the rotating points against f_j: exact (psd = false) or, for psd, the PSD
  /// projection of each bone's rotation curvature (the mixed δω–δu terms dropped).
  void mapHessian(const std::vector<int>& nodes, const std::vector<Mat3>* K,
                  const std::vector<Vec3>* forces, std::vector<Triplet>& H, int offset,
                  bool psd) const;
  mutable std::vector<int> all_nodes_;
  mutable std::vector<Vec3> node_forces_;
  mutable std::vector<Mat3> node_blocks_;
};

}  // namespace flsh::detail
