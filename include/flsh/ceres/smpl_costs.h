// Ceres cost functions for fitting SMPL pose θ, shape β and translation to keypoints: 3D
// keypoints (joints and/or surface points, e.g. mocap markers), 2D keypoints seen by pinhole
// cameras, and simple pose and shape priors. Jacobians are analytic (poseBody's
// PosedBodyJacobians, chained through the camera projection). Target flsh_ceres.
//
// Parameter blocks of the keypoint costs, in this order:
//   pose   (72)        SMPL axis-angle per joint, rad (joint b ≥ 1 relative to its parent)
//   betas  (num_betas) shape coefficients β; the model's first num_betas components (the rest
//                      are zero), num_betas ≤ K
//   trans  (3)         root translation, m
// Keypoint k is SMPL joint `joints[k]` for k < #joints, then surface vertex
// `vertices[k − #joints]`. Residual rows: 3k + c (3D, metres × weight) or 2k + c (2D, pixels ×
// weight); the squared cost Ceres minimizes is ½ Σ_k w_k² ‖·‖².
//
// Construction checks every size, index and value and throws flsh::InputError naming the
// argument, the expected and the actual; Evaluate never throws: non-finite parameters make it
// return false (Ceres then rejects the step). The costs hold the model by shared_ptr and have
// no mutable state, so Ceres may evaluate them from several threads.
#pragma once

#include <ceres/cost_function.h>
#include <ceres/sized_cost_function.h>

#include <memory>
#include <string>
#include <vector>

#include "flsh/body/body_forward.h"
#include "flsh/body/body_model.h"
#include "flsh/core/types.h"

namespace flsh::ceres_costs {

using Vec2 = Eigen::Vector2d;
/// `#N × 2` pixel coordinates, row-major.
using MatX2 = Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>;

/// Which points of the posed body are keypoints (joints first, then vertices; N in total).
struct KeypointSelection {
  std::vector<int> joints;    ///< SMPL joint indices 0..23 (posed joint centres)
  std::vector<int> vertices;  ///< surface vertex indices 0..#V−1 (points on the skin)
  int size() const { return int(joints.size() + vertices.size()); }
  /// All 24 SMPL joints.
  static KeypointSelection allJoints();
  /// All 24 joints, then a marker set as in optical motion capture: `per_bone` surface vertices
  /// on each bone (vertices skinned mostly to it, spread by farthest-point sampling on the
  /// template), so that every bone's rotation, including the twist of end bones, is observed.
  static KeypointSelection jointsAndMarkers(const BodyModel& model, int per_bone);
  /// The selected points of a posed body (size() × 3, m): posed joints, then posed vertices.
  MatX3 pick(const PosedBody& posed) const;
};

/// The posed keypoints of a selection and their analytic Jacobians: the common part of the
/// keypoint costs, usable on its own. Immutable and thread-safe.
class SmplKeypointFunction {
 public:
  /// Throws InputError if the model is null or not a finalized 24-joint body, an index is out
  /// of range, the selection is empty, or num_betas is not in 1..K (−1 means K; Ceres has no
  /// empty parameter blocks: to keep β fixed, mark its block constant).
  SmplKeypointFunction(std::shared_ptr<const BodyModel> model, KeypointSelection keypoints,
                       int num_betas = -1);

  /// Keypoints (N × 3, m) at pose (72), betas (num_betas) and trans (3). If a Jacobian pointer
  /// is not null it receives 3N × 72, 3N × num_betas or 3N × 3 (row 3k + c). Throws
  /// InputError on non-finite input (the costs check before calling).
  MatX3 evaluate(const double* pose, const double* betas, const double* trans,
                 MatX* d_pose = nullptr, MatX* d_betas = nullptr, MatX* d_trans = nullptr) const;

  int numKeypoints() const { return keypoints_.size(); }
  int numBetas() const { return num_betas_; }
  const KeypointSelection& keypoints() const { return keypoints_; }
  const BodyModel& model() const { return *model_; }

 private:
  std::shared_ptr<const BodyModel> model_;
  KeypointSelection keypoints_;
  int num_betas_;
};

/// 3D keypoints: residual_k = w_k (x_k(θ, β, trans) − observed_k), m.
class SmplKeypoints3dCost : public ceres::CostFunction {
 public:
  /// observed: N × 3, m (N = keypoints.size()); weights: N values ≥ 0 (empty: all 1).
  SmplKeypoints3dCost(std::shared_ptr<const BodyModel> model, KeypointSelection keypoints,
                      const MatX3& observed, const VecX& weights = VecX(), int num_betas = -1);

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

  const SmplKeypointFunction& keypointFunction() const { return function_; }

 private:
  SmplKeypointFunction function_;
  MatX3 observed_;
  VecX weights_;
};

/// A pinhole camera (OpenCV convention: x_cam = R x_world + t, the camera looks along +z_cam,
/// u = fx x/z + cx to the right, v = fy y/z + cy downwards).
struct PinholeCamera {
  double fx = 1000.0;                ///< focal length along u, px
  double fy = 1000.0;                ///< focal length along v, px
  double cx = 0.0;                   ///< principal point u, px
  double cy = 0.0;                   ///< principal point v, px
  Mat3 rotation = Mat3::Identity();  ///< R, world to camera (orthonormal, det +1)
  Vec3 translation = Vec3::Zero();   ///< t, world to camera, m
  /// Depth below which points are projected as if at this depth, m. Points behind (or too
  /// close to) the camera then give large but finite pixels that are continuous in the point,
  /// with zero derivative along the depth, so a solver moves them sideways into view instead
  /// of dividing by zero.
  double min_depth = 1e-3;

  /// Pixel of a world point (with the min_depth rule). If `d_point` is not null it receives
  /// d pixel / d point (2 × 3).
  Vec2 project(const Vec3& world_point, Eigen::Matrix<double, 2, 3>* d_point = nullptr) const;
  /// Throws InputError (prefixed by `what`) for non-positive or non-finite intrinsics, a
  /// rotation that is not orthonormal with det +1 (to 1e-6), a non-finite translation or
  /// min_depth ≤ 0.
  void validate(const std::string& what = "camera") const;
  /// A camera at `eye` looking at `target` with image-up direction `up` (world), px intrinsics.
  static PinholeCamera lookAt(const Vec3& eye, const Vec3& target, const Vec3& up, double fx,
                              double fy, double cx, double cy);
};

/// 2D keypoints in one camera: residual_k = w_k (π(x_k(θ, β, trans)) − observed_k), px.
class SmplKeypoints2dCost : public ceres::CostFunction {
 public:
  /// observed: N × 2, px; weights: N values ≥ 0 (empty: all 1; 0 drops a keypoint, e.g. one
  /// that a detector did not find).
  SmplKeypoints2dCost(std::shared_ptr<const BodyModel> model, KeypointSelection keypoints,
                      const PinholeCamera& camera, const MatX2& observed,
                      const VecX& weights = VecX(), int num_betas = -1);

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

  const SmplKeypointFunction& keypointFunction() const { return function_; }
  const PinholeCamera& camera() const { return camera_; }

 private:
  SmplKeypointFunction function_;
  PinholeCamera camera_;
  MatX2 observed_;
  VecX weights_;
};

/// Pose prior on the pose block (72): residual 3b + c = w_b θ_{b,c}, i.e. ½ Σ_b w_b² ‖θ_b‖²
/// pulls every joint towards the rest pose. A simple regularizer for ill-posed fits (2D
/// keypoints, twist about a bone's own axis, end joints that no keypoint sees).
class PosePriorCost : public ceres::SizedCostFunction<72, 72> {
 public:
  /// w_0 = 0 (the global orientation is free) and w_b = `weight` for b ≥ 1. Units: residual
  /// units per rad (e.g. px/rad next to 2D costs). Throws InputError for weight < 0 or NaN.
  explicit PosePriorCost(double weight = 1.0);
  /// Per-joint weights (24 values ≥ 0).
  explicit PosePriorCost(const VecX& joint_weights);

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

 private:
  VecX joint_weights_;
};

/// Shape prior on the betas block: residual = weight · β, i.e. ½ weight² ‖β‖² (β is in units
/// of the shape space's standard deviations for SMPL, so this is a Gaussian prior).
class ShapePriorCost : public ceres::CostFunction {
 public:
  /// Throws InputError for num_betas < 1 or weight < 0 or NaN.
  ShapePriorCost(int num_betas, double weight = 1.0);

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

 private:
  double weight_;
};

}  // namespace flsh::ceres_costs
