// The articulated skeleton's kinematics (ARCHITECTURE.md §2, §5), private to Simulable: surface
// vertex i at x_i = Σ_b w_ib (R_b (X_i − J_b) + t_b), skinned by the bones with the body's
// sparse weights (body/skinned_surface.h), and the chain rule from node derivatives to the
// bones. In the increment chart (δt_b, δω_b): ∂x_i/∂δt_b = w_ib I, ∂x_i/∂δω_b = −w_ib [y_ib]×
// with the lever arm y_ib = R_b (X_i − J_b); the second derivative of f·x_i in δω_b is
// w_ib rotationCurvature(f, y_ib). The state has no values of its own beyond the bones.
#pragma once

#include <utility>
#include <vector>

#include "flsh/body/skinned_surface.h"
#include "sim/hessian_blocks.h"
#include "sim/model_kinematics.h"

namespace flsh::detail {

struct SkinnedPoint;

class SkeletonKinematics final : public ModelKinematics {
 public:
  /// Borrowed, owned by the simulable: its skinned surface (rebuilt in place when the rest
  /// joints change), the rest vertices X(β) (#V × 3) and rest joints J (24 × 3), m.
  SkeletonKinematics(const SkinnedSurface& surface, const MatX3& rest, const MatX3& joints)
      : surface_(surface), rest_(rest), joints_(joints) {}

  int numSoftDofs() const override { return 0; }
  /// Keeps the bones for surface() and surfaceJacobian() (nothing is skinned ahead).
  void prepare(long, const BoneFrames& bones) const override {
    R_ = &bones.R;
    t_ = &bones.t;
  }
  void contactMargins(double* margin) const override;
  int numSurface() const override { return int(rest_.rows()); }
  /// x_i = Σ_b w_ib (R_b (X_i − J_b) + t_b); Y = X (no pose blend, no displacement).
  void surface(MatX3* x, MatX3* Y) const override;
  /// ∂x_i/∂t_b = w_ib I, ∂x_i/∂δω_b = −w_ib [y_ib]×.
  void surfaceJacobian(std::vector<Triplet>& triplets) const override;

  const SparseSkinWeights& weights() const { return surface_.weights; }
  const MatX3& restVertices() const { return rest_; }
  /// y_ib = R_b (X_i − J_b): vertex i's lever arm on bone b.
  Vec3 leverArm(const std::vector<Mat3>& R, int i, int b) const {
    return R[b] * (rest_.row(i) - joints_.row(b)).transpose();
  }
  /// World positions x (rows in the order of `vertices`) for the bones.
  void positions(const std::vector<int>& vertices, const BoneFrames& bones, MatX3& x) const;
  /// Adds Σ_j J_jᵀ f_j into g: f_j = forces.segment<3>(3j) for vertices[j] (zero forces
  /// skipped).
  void mapForces(const std::vector<int>& vertices, const VecX& forces, const std::vector<Mat3>& R,
                 VecX& g, int offset) const;
  /// Accumulates into `blocks` (per bone pair) Σ J_iᵀ K J_i over `node_blocks` ((index into
  /// vertices, K) in any order, an index may repeat) plus the curvature of the rotating points
  /// against the forces (as mapForces), Σ_i w_ib rotationCurvature(f_i, y_ib) per bone: exact,
  /// or for psd its projection on the PSD cone.
  void mapHessian(const std::vector<int>& vertices,
                  const std::vector<std::pair<int, Mat3>>& node_blocks, const VecX& forces,
                  const std::vector<Mat3>& R, bool psd, BonePairBlocks& blocks) const;
  /// Vertex i's influences and lever arms as a SkinnedPoint (sim/terms/term_blocks.h; id set by
  /// the caller).
  void point(int i, const std::vector<Mat3>& R, SkinnedPoint& p) const;
  void surfacePoint(int i, SkinnedPoint& p, bool = true) const override { point(i, *R_, p); }
  void surfaceForces(const MatX3& forces, VecX& g) const override;

 private:
  const SkinnedSurface& surface_;
  const MatX3& rest_;
  const MatX3& joints_;
  mutable const std::vector<Mat3>* R_ = nullptr;
  mutable const MatX3* t_ = nullptr;
};

}  // namespace flsh::detail
