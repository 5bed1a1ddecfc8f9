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
//
// The same class runs the ROM soft skeleton (SoftAvatar::enableReducedModel): the soft state is
// then z (3 per handle) and u_j = Σ_h φ_h(j) z_h with the avatar's bounded biharmonic basis, so
// every u-derivative maps to z by the chain rule (∂/∂z_h = Σ_j φ_h(j) ∂/∂u_j; Hessian blocks
// (i, j) go to (h, k) with φ_h(i) φ_k(j)). With the elastic cubature the elastic sum runs over
// the sample tets with their weights; with the inertial cubature inertia and gravity use the
// cubature's node masses (a few nodes instead of all). Only the nodes some term reads are
// skinned per evaluation: the mass nodes, and the surface nodes contact or output ask for; their
// pose blend offsets are evaluated when first read.
#pragma once

#include <functional>
#include <vector>

#include "flsh/contact/collider.h"
#include "flsh/contact/contact_energy.h"
#include "flsh/core/types.h"
#include "flsh/sim/fem_material.h"
#include "flsh/sim/skeleton_energies.h"
#include "flsh/volume/soft_avatar.h"
#include "hessian_blocks.h"

namespace flsh {
struct FixedHessianBlocks;  // flsh/sim/simulable.h
}

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
  bool reduced() const { return reduced_; }
  int numSoftDofs() const { return 3 * int(state_nodes_.size()); }
  /// The node of each 3-value block of the soft state: the soft-tissue nodes (FEM) or the handles
  /// (ROM, where u at a handle is its z_h: φ_h = 1 there and every other φ is 0).
  const VecXi& softNodes() const { return state_nodes_; }
  /// Offset in the soft state of the 3 values that are node j's displacement, −1 when u_j is not
  /// a state entry of its own (bone nodes; in the ROM every node but the handles).
  int nodeDof(int j) const { return reduced_ ? state_dof_[j] : node_dof_[j]; }
  /// u_j for a soft state (m, unposed space; zero on bone nodes).
  Vec3 displacementOf(const VecX& state, int j) const { return nodeDisplacement(state, j); }
  /// ∂u_j/∂(soft state) as (state offset, weight) pairs: u_j = Σ weight · state.segment<3>(offset).
  void displacementBasis(int j, std::vector<std::pair<int, double>>& out) const;

  // ---- state (the bones live in Simulable) ----
  VecX u, u_n, u_nm1;  ///< the soft state: 3 · #soft nodes (FEM, u, m) or 3 · #handles (ROM, z, m)

  /// Held pose blend offsets P (#N × 3, m) from the bones' rotations (relative rotations
  /// R_pᵀ R_b give the pose feature). The FEM evaluates every node's; the ROM keeps the feature
  /// and evaluates a node's offset when first read (blendOf).
  void setPoseBlend(const std::vector<Mat3>& R);
  const MatX3& poseBlend() const;  ///< every node's (evaluates the missing ones)
  void setPoseBlendOffsets(const MatX3& offsets);

  /// World positions x (#N × 3) of every node for bones and a soft state.
  void positions(const BoneFrames& bones, const VecX& displacement, MatX3& x) const;
  /// x̂ = 2 x(q_n) − x(q_{n−1}) with the held pose blend (it carries no momentum).
  void setPrediction(const BoneFrames& bones_n, const BoneFrames& bones_nm1);

  /// Evaluates the node positions of the current state (bones + u); cached by `version`.
  void prepare(long version, const BoneFrames& bones) const;
  /// Node positions of the prepared state: every node in the FEM; in the ROM only the mass
  /// nodes (surface() for the surface, positions() for every node).
  const MatX3& currentPositions() const { return x_; }

  // ---- energies at the prepared state; gradients ADDED at offset (bones at offset, u at
  // offset + bone_dofs), Hessian triplets APPENDED (both triangles) ----
  /// `blocks` (FEM only; may be null): the bone–tissue coupling and node-diagonal blocks are
  /// returned through it (fixed positions, one list per energy) instead of appended to H.
  double inertia(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                 FixedHessianBlocks* blocks = nullptr) const;
  double gravity(const Vec3& gravity, VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                 FixedHessianBlocks* blocks = nullptr) const;
  /// `blocks` (FEM only; may be null): the node-pair blocks are returned through it (positions
  /// fixed, column-major) instead of appended to H.
  double elastic(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                 FixedHessianBlocks* blocks = nullptr) const;
  /// Penalty contact of the surface nodes against colliders at time t: of `candidates` (surface
  /// node indices; a broad phase's: the others must be out of contact) or, null, every one.
  double contact(const std::vector<Collider>& colliders, double time,
                 const ContactOptions& options, VecX* g, std::vector<Triplet>* H, int offset,
                 bool psd, int* active = nullptr,
                 const std::vector<int>* candidates = nullptr, bool skin = true) const;
  /// ROM: skins surface nodes for a later contact(..., skin = false) (no-op for the FEM, whose
  /// prepare() skins every node).
  void skinSurfaceNodes(const std::vector<int>& nodes) const {
    if (reduced_) skinNodes(nodes);
  }
  /// ROM (no-op for the FEM): the Hessian terms' bone–z and z–z blocks are summed at fixed
  /// positions (every pair the basis, the skinning and the elastic tets can couple) into value
  /// list 0 (inertia: the dynamic Hessian) or 1 (gravity, elasticity, contact: the potential
  /// one). beginReduced zeroes a list; after the terms of one evaluation flushReduced appends
  /// its blocks to H as triplets or, with `blocks`, returns the list as fixed blocks (valid
  /// until the next beginReduced of that list). The terms of the two lists share no scratch
  /// (mapHessian's is per list too): inertia may run concurrently with the potential terms
  /// other than contact, which skins surface nodes.
  void beginReduced(int list) const;
  void flushReduced(int list, std::vector<Triplet>& H, int offset,
                    std::vector<FixedHessianBlocks>* blocks = nullptr) const;
  /// ROM: inertia's, gravity's and the elastic term's gradients, and `potential_first`'s
  /// (e.g. contact, on nodes skinned before, with skin = false), added into g on two threads:
  /// inertia and gravity (one mapping of their summed node forces) with the first elastic tets
  /// into g, beside potential_first and the other tets into a scratch vector of g's size (added
  /// into g after). Returns the energy of inertia, gravity and the elastic term (not
  /// potential_first's), which the same passes give.
  double reducedGradient(const Vec3& gravity, VecX& g, int offset,
                         const std::function<void(VecX&)>& potential_first) const;
  /// ROM: both Hessian parts' node and tet terms on two threads (Simulable::
  /// getHessianTripletVector): inertia (value list 0, bone triplets into H_dynamic) beside
  /// `potential_first` (may be empty: e.g. contact, on nodes skinned before, with skin = false),
  /// then gravity, the elastic tets and the exact rest-stiffness term (list 1, bone triplets
  /// into H_potential); a share of inertia's mass nodes is mapped on the second thread too
  /// (into list 1 and H_potential), to balance the two. Both lists come back mirrored
  /// (flushReduced then only hands them over).
  void reducedHessians(const Vec3& gravity, std::vector<Triplet>& H_dynamic,
                       std::vector<Triplet>& H_potential, int offset, bool psd,
                       const std::function<void()>& potential_first) const;

  /// Bounds for a contact broad phase: ‖Y_i − X̄_i‖ ≤ blendBound(i) · poseFeatureNorm() +
  /// displacementWeight(i) · largestSoftState() for surface node i (pose blend plus
  /// displacement; u_i = Σ w z over nodeDisplacementBasis with Σ w = displacementWeight).
  double blendBound(int i) const { return blend_bound_[i]; }
  double displacementWeight(int i) const;
  double poseFeatureNorm() const { return feature_.norm(); }
  double largestSoftState() const;  ///< max over the 3-blocks of the soft state of ‖·‖, m
  /// World positions and unposed nodes of every surface node (#V × 3) at the prepared state.
  void surface(MatX3* x, MatX3* Y) const;

  /// d(surface nodes)/dq rows (3#V × numDofs) as triplets.
  void surfaceJacobian(std::vector<Triplet>& triplets) const;

 private:
  struct Influence {
    int bone;
    double weight;
  };
  int num_bones_ = 0, num_surface_ = 0, bone_dofs_ = 0;
  bool reduced_ = false;
  double h_ = 0.0;
  MatX3 rest_;          // #N × 3, X̄(β)
  const MatX* posedirs_ = nullptr;  // 3#N × 207 (owned by the avatar's template)
  std::vector<int> parents_;
  MatX3 joints_;        // 24 × 3
  // Pose blend: the feature (9 · 23) of the held pose; FEM: every node's offsets in blend_.
  // ROM: blend_ row j is current when blend_stamp_[j] == pose_stamp_, else blendOf evaluates it
  // from posedirs_T_ (each node's 207 × 3 block contiguous, for the nodes with a slot: the
  // surface and the mass nodes), else from posedirs.
  VecX feature_;
  mutable MatX3 blend_;  // #N × 3
  int pose_stamp_ = 0;
  mutable std::vector<int> blend_stamp_;
  MatX posedirs_T_;
  std::vector<int> blend_slot_;
  VecX blend_bound_;     // #V: ‖posedirs rows of surface node i‖_F
  VecX phi_sum_;         // #V (ROM): Σ_h φ_h(i)
  VecX mass_;           // #N
  VecXi state_nodes_;
  std::vector<int> node_dof_;  // FEM layout: 3 · (rank among soft nodes), −1 on bone nodes
  // ROM: u_j = Σ φ z_h over phi_[phi_start_[j] .. phi_start_[j + 1]) as (handle, φ); the
  // handle's z offset (3h) at a handle node, −1 elsewhere.
  std::vector<int> phi_start_;
  std::vector<std::pair<int, double>> phi_;
  std::vector<int> state_dof_;
  int num_handles_ = 0;
  // Nodes skinned by prepare() (all in the FEM), nodes with inertia mass, their masses (lumped,
  // or the inertial cubature's) and the elastic tets' weights (1, or the elastic cubature's).
  std::vector<int> eval_nodes_, mass_nodes_;
  VecX inertia_mass_;
  VecX element_weight_;
  // ROM: elastic tet e's handles tet_handles_[tet_handle_start_[e] ..) and the tet's shape
  // gradients through the basis, G̃_e = G_e Φ_e (columns of tet_gradients_ at the same offsets).
  std::vector<int> tet_handle_start_, tet_handles_;
  Mat3X tet_gradients_;
  int max_tet_handles_ = 0;
  // ROM with the elastic cubature (the rest-stiffness split, ReducedData::elastic_rest_stiffness):
  // the exact rest stiffness K of ½ zᵀ K z and the handle pairs whose 3 × 3 block is nonzero;
  // each elastic tet's own rest Hessian K̃_e in its handles' coordinates ((3 n_e)² values,
  // column-major, from rest_hessian_start_[e]).
  MatX rest_stiffness_;
  std::vector<std::pair<int, int>> rest_stiffness_blocks_;
  std::vector<int> rest_hessian_start_;
  VecX rest_hessians_;
  VecX rest_floors_;  // the split's floor c_e per elastic tet (restSplitFloors)
  std::vector<int> influence_start_;
  std::vector<Influence> influences_;
  MatX3 x_hat_;
  VecX areas_;          // #V surface vertex areas, m²

  // Elements.
  MatX4i tets_;
  std::vector<TetElementRest> elements_;
  std::vector<FemMaterialPoint> materials_;
  // FEM elastic Hessian: one 3 × 3 block ∂²E/∂u_row∂u_col per pair of soft nodes sharing a
  // tet, at block_dofs_ (row, column DoF relative to the simulable's first DoF; column-major
  // order); element e's local block (a, b) adds into block tet_block_[16 e + 4 a + b] (−1: a
  // bone node).
  std::vector<int> tet_block_;
  std::vector<std::pair<int, int>> block_dofs_;

  // Caches of the prepared state.
  mutable long version_ = -1;
  mutable MatX3 x_, Y_;
  mutable std::vector<Mat3> node_M_;  // M_j = Σ_b w_jb R_b
  mutable std::vector<Vec12> element_gradients_;
  mutable std::vector<Mat12> element_hessians_;
  mutable std::vector<Mat3> blocks_;
  mutable BonePairBlocks pair_blocks_[2];  // mapHessian's, per value list
  // mapHessian with K_j = κ_j I: per ordered bone pair (b, c) (key b · #bones + c), Σ κ w_b w_c
  // (s), its sums weighted by r_c (p) and r_b (q), and Σ κ w_b w_c r_c r_bᵀ (W); per value list.
  struct PairMoments {
    double s = 0.0;
    Vec3 p = Vec3::Zero(), q = Vec3::Zero();
    Mat3 W = Mat3::Zero();
  };
  mutable TouchedValues<PairMoments> pair_moments_[2];
  mutable std::vector<double> node_scalars_;  // inertia's κ_j = m_j / h²
  // ROM Hessian blocks at fixed positions (buildReducedPattern): z–z blocks (zz_slot_[h · H +
  // k], H handles), bone–z blocks (bz_slot_[r · H + h], r = 2b for bone b's t rows, 2b + 1 for
  // its ω rows), then the bone–z blocks' transposes; positions relative to the first DoF. Two
  // value lists: 0 (inertia), 1 (the potential terms).
  std::vector<int> zz_slot_, bz_slot_;
  int num_zz_ = 0, num_bz_ = 0;
  std::vector<std::pair<int, int>> zz_mirror_;  // (slot of (h, k), slot of (k, h)) for h > k
  std::vector<std::pair<int, int>> reduced_positions_;
  mutable std::vector<Mat3> reduced_values_[2];
  mutable bool mirrored_[2] = {false, false};  // the lower blocks are current
  mutable VecX gradient_scratch_;
  /// Lower z–z and z–bone blocks from the summed ones, in the part-th of parts ranges.
  void mirrorReduced(int list, int part, int parts) const;
  // Bones of the prepared state (the simulable's, which outlive every evaluation).
  mutable const std::vector<Mat3>* cur_R_ = nullptr;
  mutable const MatX3* cur_t_ = nullptr;

  Eigen::Matrix<double, 3, 4> elementDisplacement(int e) const;
  void buildReducedPattern();
  double elasticReduced(VecX* g, std::vector<Mat3>* list, int offset, bool psd) const;
  /// Elastic tets [first, last): energy returned, gradient added into gz (the handles' 3H
  /// entries; may be null), Hessian blocks summed into `values` (a value list; may be null).
  double elasticTets(int first, int last, double* gz, Mat3* values, bool psd) const;
  /// The floors c_e of the split's excess (f_e ≥ −c_e q_e) per elastic tet: restSplitFloors
  /// (fem_material.h) of K and the sample tets' rest Hessians, so that the energy keeps at least
  /// half of K in every direction.
  VecX restSplitFloors() const;
  /// ½ zᵀ K z (0 without the elastic cubature), its gradient and Hessian blocks.
  double restStiffnessTerm(VecX* g, Mat3* values, int offset) const;
  /// Elastic tet e (count handles, cubature weight w, their displacements Z) under the
  /// rest-stiffness split: its weighted excess over its rest quadratic, bounded below
  /// (ReducedData::elastic_rest_stiffness); gradient and Hessian (in the handles' coordinates,
  /// weighted) written into the views when asked.
  double sampleTetExcess(int e, int count, double w, const Eigen::Ref<const Mat3X>& Z,
                         bool want_gradient, bool want_hessian, bool psd, Eigen::Ref<VecX> gradient,
                         Eigen::Ref<MatX> hessian) const;
  Vec3 nodeDisplacement(const VecX& state, int j) const {
    if (!reduced_)
      return node_dof_[j] < 0 ? Vec3::Zero() : Vec3(state.segment<3>(node_dof_[j]));
    Vec3 d = Vec3::Zero();
    for (int k = phi_start_[j]; k < phi_start_[j + 1]; ++k)
      d += phi_[k].second * state.segment<3>(3 * phi_[k].first);
    return d;
  }
  /// x rows of `nodes` (distinct; split over the threads from 512) for bones and a state.
  void positionsOf(const std::vector<int>& nodes, const BoneFrames& bones, const VecX& state,
                   MatX3& x) const;
  Vec3 blendOf(int j) const;
  /// Y_, x_ and node_M_ rows of `nodes` (distinct; split over the threads from 512) at the
  /// prepared state.
  void skinNodes(const std::vector<int>& nodes) const;
  // Chain rule to the soft state: g(u_j) += v; H(bone row block at `row` (6b or 6b + 3), u_j) +=
  // B and its transpose; H(u_j, u_j) += B (symmetric). FEM: straight to g / triplets; ROM:
  // through φ into the z entries / value list `list` (flushReduced emits it).
  void addSoftGradient(VecX& g, int offset, int j, const Vec3& v) const;
  template <int Rows>
  void addBoneSoft(std::vector<Triplet>& H, int offset, int row, int j,
                   const Eigen::Matrix<double, Rows, 3>& B, int list) const;
  void addSoftSoft(std::vector<Triplet>& H, int offset, int j, const Mat3& B, int list) const;
  /// Adds Σ_j J_jᵀ f_j (f: per-node ∂E/∂x_j for the listed nodes) into g.
  void mapForces(const std::vector<int>& nodes, const std::vector<Vec3>& forces, VecX& g,
                 int offset) const;
  /// Appends Σ_j J_jᵀ K_j J_j (K_j symmetric 3 × 3; null = none) plus, when `forces` is given,
  /// the curvature of the rotating points against f_j: exact (psd = false) or, for psd, the PSD
  /// projection of each bone's rotation curvature (the mixed δω–δu terms dropped).
  /// `fixed` (FEM, nodes = mass_nodes_ only; may be null): the bone–tissue coupling and
  /// node-diagonal blocks go into it, laid out as coupling_dofs_, instead of into H.
  /// `list`: the ROM value list and the scratch to use (0: inertia, 1: the potential terms).
  /// `K_scalar` (instead of K, which is then null): K_j = K_scalar[idx] · I (inertia).
  void mapHessian(const std::vector<int>& nodes, const std::vector<Mat3>* K,
                  const std::vector<Vec3>* forces, std::vector<Triplet>& H, int offset,
                  bool psd, int list, std::vector<Mat3>* fixed = nullptr,
                  const std::vector<double>* K_scalar = nullptr) const;
  // FEM: the fixed positions (relative to the simulable's first DoF) of the blocks mapHessian
  // writes for the mass nodes: per mass node with a DoF, from coupling_start_[idx], four per
  // influence a of bone b — (6b, u), (6b + 3, u), (u, 6b), (u, 6b + 3) — then (u, u).
  std::vector<std::pair<int, int>> coupling_dofs_;
  std::vector<int> coupling_start_;
  mutable std::vector<Mat3> inertia_fixed_, gravity_fixed_;
  // ROM: gravity's rotation–handle blocks, D_bh [g]× R_b into value list 1 at `slot`
  // (reducedGravityHessian), D_bh = Σ_j m_j w_jb φ_jh over the mass nodes.
  struct GravityHandle {
    int slot, bone;
    double weight;
  };
  std::vector<GravityHandle> gravity_handles_;
  void reducedGravityHessian(const Vec3& gravity, std::vector<Triplet>& H, int offset,
                             bool psd) const;
  // ROM: the mass nodes in two parts for reducedHessians' two threads (the last share beside
  // the potential terms, soft_tissue.cpp), with each part's κ_j = m_j / h² and node forces;
  // inertiaHessianPart maps one part into value list `part`.
  std::vector<int> mass_node_parts_[2];
  mutable std::vector<double> part_scalars_[2];
  mutable std::vector<Vec3> part_forces_[2];
  void splitMassNodes();
  void inertiaHessianPart(int part, std::vector<Triplet>& H, int offset, bool psd) const;
  std::vector<int> all_nodes_, surface_nodes_;
  mutable MatX3 contact_x_;
  mutable VecX contact_areas_;
  mutable std::vector<Vec3> node_forces_[2];  // inertia's, gravity's
  mutable std::vector<Mat3> node_blocks_;
};

}  // namespace flsh::detail
