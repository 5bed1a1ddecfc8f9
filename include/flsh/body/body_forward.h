// SMPL forward pass (linear blend skinning with shape and pose blend shapes) and its analytic
// Jacobians with respect to shape β, pose θ and translation (ARCHITECTURE.md §2).
//
// Conventions: θ holds 24 axis-angle vectors (72 values, SMPL order) or SMPL-H's 156
// (converted by toSmplPose). β may be shorter than the model's K (zero padded), not longer.
#pragma once

#include <string>
#include <vector>

#include "flsh/body/body_model.h"

namespace flsh {

/// Largest |β_k| the forward pass accepts: shape coefficients are in standard deviations of
/// the shape space (|β| ≲ 5 for real people), so 100 is far outside any body and still keeps
/// every derived position finite.
constexpr double kMaxShapeCoefficient = 100.0;

/// Throws InputError naming `what` and the value unless every β_k is finite and within
/// ±kMaxShapeCoefficient.
void checkShapeCoefficients(const Eigen::Ref<const VecX>& betas, const std::string& what);

/// Result of posing one frame.
struct PosedBody {
  MatX3 vertices;     ///< #V × 3 world vertex positions, m (includes trans).
  MatX3 joints;       ///< 24 × 3 posed joint centres, m (includes trans).
  MatX3 rest_joints;  ///< 24 × 3 joint centres of the shaped T-pose, J(β) = J_regressor v_shaped.
  /// 24 global rigid transforms G_j (4 × 4): rotation of bone j and, as translation, the posed
  /// joint centre (without trans). A vertex rigidly attached to bone j maps as
  /// x ↦ R_j (x − J_j) + t_j (+ trans).
  std::vector<Mat4> transforms;
};

/// Analytic Jacobians of one frame, row 3i + c = coordinate c of vertex (or joint) i.
struct PosedBodyJacobians {
  MatX vertices_betas;  ///< 3#V × K
  MatX vertices_pose;   ///< 3#V × 72
  MatX vertices_trans;  ///< 3#V × 3 (identity blocks)
  MatX joints_betas;    ///< 72 × K
  MatX joints_pose;     ///< 72 × 72
  MatX joints_trans;    ///< 72 × 3 (identity blocks)
};

/// Poses one frame. If `jacobians` is not null it is filled too. Throws InputError on sizes,
/// non-finite values, |β_k| > kMaxShapeCoefficient or joint angles above kMaxRotationAngle.
/// Thread-safe (the model is read only).
PosedBody poseBody(const BodyModel& model, const Eigen::Ref<const VecX>& betas,
                   const Eigen::Ref<const VecX>& pose, const Vec3& trans = Vec3::Zero(),
                   PosedBodyJacobians* jacobians = nullptr);

/// Vertices and joints of a sequence.
struct PosedBatch {
  RowMatX vertices;  ///< T × 3#V (frame t, vertex i, coordinate c at column 3i + c)
  RowMatX joints;    ///< T × 72
};

/// Poses T frames (poses T × 72 or T × 156, trans T × 3; β shared) in parallel over frames.
PosedBatch poseBodyBatch(const BodyModel& model, const Eigen::Ref<const VecX>& betas,
                         const Eigen::Ref<const RowMatX>& poses,
                         const Eigen::Ref<const RowMatX>& trans);

/// Shaped T-pose vertices v_template + shapedirs·β (#V × 3).
MatX3 shapedVertices(const BodyModel& model, const Eigen::Ref<const VecX>& betas);

}  // namespace flsh
