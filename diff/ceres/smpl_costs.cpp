// Ceres cost functions for SMPL keypoint fitting (include/flsh/ceres/smpl_costs.h).
#include "flsh/ceres/smpl_costs.h"

#include <Eigen/Geometry>
#include <Eigen/LU>
#include <cmath>
#include <exception>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "flsh/body/body_forward.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/core/error.h"

namespace flsh::ceres_costs {

namespace {

std::string count(long n) { return std::to_string(n); }

/// Residual weights: N values ≥ 0 and finite, or all ones when `weights` is empty.
VecX checkedWeights(const VecX& weights, int n, const std::string& what) {
  if (weights.size() == 0) return VecX::Ones(n);
  if (weights.size() != n)
    throw InputError(what + ": weights has " + count(weights.size()) +
                     " values, expected one per keypoint (" + count(n) + ")");
  for (int k = 0; k < n; ++k)
    if (!(std::isfinite(weights[k]) && weights[k] >= 0.0))
      throw InputError(what + ": weights[" + count(k) + "] must be finite and ≥ 0, got " +
                       std::to_string(weights[k]));
  return weights;
}

template <class M>
void requireFiniteObservations(const M& observed, int n, int dims, const std::string& what) {
  if (observed.rows() != n)
    throw InputError(what + ": observed has shape " + shapeString({long(observed.rows()), dims}) +
                     ", expected " + shapeString({n, dims}) + " (one row per keypoint)");
  if (!observed.allFinite()) throw InputError(what + ": observed contains NaN or Inf");
}

bool allFinite(const double* values, int n) {
  for (int i = 0; i < n; ++i)
    if (!std::isfinite(values[i])) return false;
  return true;
}

/// Writes a dense Jacobian block into Ceres' row-major buffer (rows × cols).
void writeRowMajor(const MatX& block, double* out) {
  Eigen::Map<RowMatX>(out, block.rows(), block.cols()) = block;
}

/// Keypoint costs share this: validate parameters, evaluate, and hand the Jacobian blocks that
/// Ceres asked for (nullptr entries are blocks it holds constant).
bool evaluateKeypoints(const SmplKeypointFunction& f, double const* const* parameters,
                       double** jacobians, MatX3& points, MatX* d_pose, MatX* d_betas,
                       MatX* d_trans) {
  if (!allFinite(parameters[0], kSmplPoseSize) || !allFinite(parameters[1], f.numBetas()) ||
      !allFinite(parameters[2], 3))
    return false;
  const bool want = jacobians != nullptr;
  try {
    points = f.evaluate(
        parameters[0], parameters[1], parameters[2], want && jacobians[0] ? d_pose : nullptr,
        want && jacobians[1] ? d_betas : nullptr, want && jacobians[2] ? d_trans : nullptr);
  } catch (const std::exception&) {
    // Cannot happen for finite parameters of a validated model; Ceres must not see exceptions.
    return false;
  }
  return true;
}

}  // namespace

// ---------------------------------------------------------------------------------------------

KeypointSelection KeypointSelection::allJoints() {
  KeypointSelection s;
  for (int j = 0; j < kNumJoints; ++j) s.joints.push_back(j);
  return s;
}

KeypointSelection KeypointSelection::jointsAndMarkers(const BodyModel& model, int per_bone) {
  if (per_bone < 0) throw InputError("jointsAndMarkers: per_bone = " + std::to_string(per_bone) +
                                     ", expected ≥ 0");
  KeypointSelection s = allJoints();
  for (int j = 0; j < model.numJoints(); ++j) {
    Eigen::Index best;
    model.weights.col(j).maxCoeff(&best);
    if (per_bone == 0 || model.weights(best, j) <= 0) continue;
    std::vector<int> candidates;
    for (int i = 0; i < model.numVertices(); ++i)
      if (model.weights(i, j) >= 0.5 * model.weights(best, j)) candidates.push_back(i);
    std::vector<int> chosen = {int(best)};
    while (int(chosen.size()) < per_bone && chosen.size() < candidates.size()) {
      int farthest = candidates[0];
      double farthest_distance = -1.0;
      for (int i : candidates) {
        double d = std::numeric_limits<double>::infinity();
        for (int c : chosen)
          d = std::min(d, (model.v_template.row(i) - model.v_template.row(c)).norm());
        if (d > farthest_distance) farthest_distance = d, farthest = i;
      }
      chosen.push_back(farthest);
    }
    s.vertices.insert(s.vertices.end(), chosen.begin(), chosen.end());
  }
  return s;
}

MatX3 KeypointSelection::pick(const PosedBody& posed) const {
  MatX3 x(size(), 3);
  const int nj = int(joints.size());
  for (int k = 0; k < nj; ++k) x.row(k) = posed.joints.row(joints[k]);
  for (int k = nj; k < size(); ++k) x.row(k) = posed.vertices.row(vertices[k - nj]);
  return x;
}

SmplKeypointFunction::SmplKeypointFunction(std::shared_ptr<const BodyModel> model,
                                           KeypointSelection keypoints, int num_betas)
    : model_(std::move(model)), keypoints_(std::move(keypoints)) {
  const std::string what = "SmplKeypointFunction";
  if (!model_) throw InputError(what + ": model is null");
  if (model_->numJoints() != kNumJoints)
    throw InputError(what + ": model '" + model_->source + "' has " + count(model_->numJoints()) +
                     " joints, expected " + count(kNumJoints));
  // A trial pose surfaces an unfinalized or inconsistent model here, not inside Evaluate.
  poseBody(*model_, VecX::Zero(0), VecX::Zero(kSmplPoseSize));
  if (keypoints_.size() == 0)
    throw InputError(what + ": the keypoint selection is empty (no joints, no vertices)");
  for (size_t k = 0; k < keypoints_.joints.size(); ++k)
    if (keypoints_.joints[k] < 0 || keypoints_.joints[k] >= kNumJoints)
      throw InputError(what + ": joints[" + count(long(k)) + "] = " + count(keypoints_.joints[k]) +
                       " is not a joint index in 0.." + count(kNumJoints - 1));
  const int V = model_->numVertices();
  for (size_t k = 0; k < keypoints_.vertices.size(); ++k)
    if (keypoints_.vertices[k] < 0 || keypoints_.vertices[k] >= V)
      throw InputError(what + ": vertices[" + count(long(k)) +
                       "] = " + count(keypoints_.vertices[k]) + " is not a vertex index in 0.." +
                       count(V - 1) + " of model '" + model_->source + "'");
  const int K = model_->numBetas();
  num_betas_ = num_betas < 0 ? K : num_betas;
  if (num_betas_ < 1 || num_betas_ > K)
    throw InputError(what + ": num_betas = " + count(num_betas) + ", expected 1.." + count(K) +
                     " (the model's shape components) or −1 for all");
}

MatX3 SmplKeypointFunction::evaluate(const double* pose, const double* betas, const double* trans,
                                     MatX* d_pose, MatX* d_betas, MatX* d_trans) const {
  const Eigen::Map<const VecX> pose_vector(pose, kSmplPoseSize);
  const Eigen::Map<const VecX> betas_vector(betas, num_betas_);
  const Vec3 translation(trans[0], trans[1], trans[2]);
  const bool need_jacobians = d_pose || d_betas || d_trans;
  PosedBodyJacobians jac;
  const PosedBody posed =
      poseBody(*model_, betas_vector, pose_vector, translation, need_jacobians ? &jac : nullptr);

  const int nj = int(keypoints_.joints.size());
  const int N = numKeypoints();
  MatX3 points = keypoints_.pick(posed);
  if (!need_jacobians) return points;

  // Row 3k + c of each Jacobian: joint rows come from joints_*, vertex rows from vertices_*.
  const auto gather = [&](const MatX& joint_rows, const MatX& vertex_rows, int cols, MatX* out) {
    if (!out) return;
    out->resize(3 * N, cols);
    for (int k = 0; k < nj; ++k)
      out->middleRows<3>(3 * k) = joint_rows.block(3 * keypoints_.joints[k], 0, 3, cols);
    for (int k = nj; k < N; ++k)
      out->middleRows<3>(3 * k) = vertex_rows.block(3 * keypoints_.vertices[k - nj], 0, 3, cols);
  };
  gather(jac.joints_pose, jac.vertices_pose, kSmplPoseSize, d_pose);
  gather(jac.joints_betas, jac.vertices_betas, num_betas_, d_betas);
  gather(jac.joints_trans, jac.vertices_trans, 3, d_trans);
  return points;
}

// ---------------------------------------------------------------------------------------------

SmplKeypoints3dCost::SmplKeypoints3dCost(std::shared_ptr<const BodyModel> model,
                                         KeypointSelection keypoints, const MatX3& observed,
                                         const VecX& weights, int num_betas)
    : function_(std::move(model), std::move(keypoints), num_betas), observed_(observed) {
  const int N = function_.numKeypoints();
  requireFiniteObservations(observed_, N, 3, "SmplKeypoints3dCost");
  weights_ = checkedWeights(weights, N, "SmplKeypoints3dCost");
  set_num_residuals(3 * N);
  *mutable_parameter_block_sizes() = {kSmplPoseSize, function_.numBetas(), 3};
}

bool SmplKeypoints3dCost::Evaluate(double const* const* parameters, double* residuals,
                                   double** jacobians) const {
  MatX3 points;
  MatX d_pose, d_betas, d_trans;
  if (!evaluateKeypoints(function_, parameters, jacobians, points, &d_pose, &d_betas, &d_trans))
    return false;
  const int N = function_.numKeypoints();
  for (int k = 0; k < N; ++k)
    for (int c = 0; c < 3; ++c)
      residuals[3 * k + c] = weights_[k] * (points(k, c) - observed_(k, c));
  if (!jacobians) return true;
  // Row 3k + c scales by w_k.
  const VecX row_weights = weights_.replicate(1, 3).transpose().reshaped();
  if (jacobians[0]) writeRowMajor(row_weights.asDiagonal() * d_pose, jacobians[0]);
  if (jacobians[1]) writeRowMajor(row_weights.asDiagonal() * d_betas, jacobians[1]);
  if (jacobians[2]) writeRowMajor(row_weights.asDiagonal() * d_trans, jacobians[2]);
  return true;
}

// ---------------------------------------------------------------------------------------------

Vec2 PinholeCamera::project(const Vec3& world_point, Eigen::Matrix<double, 2, 3>* d_point) const {
  const Vec3 p = rotation * world_point + translation;
  const bool clamped = p.z() < min_depth;
  const double z = clamped ? min_depth : p.z();
  const Vec2 pixel(fx * p.x() / z + cx, fy * p.y() / z + cy);
  if (d_point) {
    Eigen::Matrix<double, 2, 3> d_camera;
    d_camera << fx / z, 0.0, clamped ? 0.0 : -fx * p.x() / (z * z),  //
        0.0, fy / z, clamped ? 0.0 : -fy * p.y() / (z * z);
    *d_point = d_camera * rotation;
  }
  return pixel;
}

void PinholeCamera::validate(const std::string& what) const {
  const auto positive = [&](double v, const char* name) {
    if (!(std::isfinite(v) && v > 0.0))
      throw InputError(what + ": " + name + " must be finite and > 0, got " + std::to_string(v));
  };
  positive(fx, "fx (px)");
  positive(fy, "fy (px)");
  positive(min_depth, "min_depth (m)");
  if (!std::isfinite(cx) || !std::isfinite(cy))
    throw InputError(what + ": the principal point (cx, cy) must be finite, got (" +
                     std::to_string(cx) + ", " + std::to_string(cy) + ")");
  if (!translation.allFinite()) throw InputError(what + ": translation contains NaN or Inf");
  if (!rotation.allFinite()) throw InputError(what + ": rotation contains NaN or Inf");
  const double orthogonality =
      (rotation.transpose() * rotation - Mat3::Identity()).cwiseAbs().maxCoeff();
  const double det = rotation.determinant();
  if (orthogonality > 1e-6 || std::abs(det - 1.0) > 1e-6)
    throw InputError(what +
                     ": rotation must be a rotation matrix (RᵀR = I, det R = +1 to 1e-6); "
                     "got max |RᵀR − I| = " +
                     std::to_string(orthogonality) + ", det R = " + std::to_string(det));
}

PinholeCamera PinholeCamera::lookAt(const Vec3& eye, const Vec3& target, const Vec3& up, double fx,
                                    double fy, double cx, double cy) {
  const Vec3 forward_raw = target - eye;
  if (!(forward_raw.allFinite() && up.allFinite()) || forward_raw.norm() == 0.0)
    throw InputError("PinholeCamera::lookAt: eye and target must be finite and distinct");
  const Vec3 forward = forward_raw.normalized();
  const Vec3 right_raw = forward.cross(up);
  if (right_raw.norm() < 1e-9 * up.norm() || up.norm() == 0.0)
    throw InputError(
        "PinholeCamera::lookAt: up must be nonzero and not parallel to the view "
        "direction");
  const Vec3 right = right_raw.normalized();
  const Vec3 down = forward.cross(right);
  PinholeCamera camera;
  camera.fx = fx;
  camera.fy = fy;
  camera.cx = cx;
  camera.cy = cy;
  camera.rotation.row(0) = right.transpose();
  camera.rotation.row(1) = down.transpose();
  camera.rotation.row(2) = forward.transpose();
  camera.translation = -camera.rotation * eye;
  camera.validate("PinholeCamera::lookAt");
  return camera;
}

SmplKeypoints2dCost::SmplKeypoints2dCost(std::shared_ptr<const BodyModel> model,
                                         KeypointSelection keypoints, const PinholeCamera& camera,
                                         const MatX2& observed, const VecX& weights, int num_betas)
    : function_(std::move(model), std::move(keypoints), num_betas),
      camera_(camera),
      observed_(observed) {
  const int N = function_.numKeypoints();
  camera_.validate("SmplKeypoints2dCost: camera");
  requireFiniteObservations(observed_, N, 2, "SmplKeypoints2dCost");
  weights_ = checkedWeights(weights, N, "SmplKeypoints2dCost");
  set_num_residuals(2 * N);
  *mutable_parameter_block_sizes() = {kSmplPoseSize, function_.numBetas(), 3};
}

bool SmplKeypoints2dCost::Evaluate(double const* const* parameters, double* residuals,
                                   double** jacobians) const {
  MatX3 points;
  MatX d_pose, d_betas, d_trans;
  if (!evaluateKeypoints(function_, parameters, jacobians, points, &d_pose, &d_betas, &d_trans))
    return false;
  const int N = function_.numKeypoints();
  const bool want = jacobians != nullptr;
  // Block-diagonal chain: rows 2k..2k+1 = w_k · dπ/dx (2 × 3) · rows 3k..3k+2 of the 3D one.
  std::vector<Eigen::Matrix<double, 2, 3>> projection(want ? N : 0);
  for (int k = 0; k < N; ++k) {
    Eigen::Matrix<double, 2, 3> d_pixel;
    const Vec2 pixel = camera_.project(points.row(k).transpose(), want ? &d_pixel : nullptr);
    residuals[2 * k] = weights_[k] * (pixel.x() - observed_(k, 0));
    residuals[2 * k + 1] = weights_[k] * (pixel.y() - observed_(k, 1));
    if (want) projection[k] = weights_[k] * d_pixel;
  }
  if (!want) return true;
  const auto chain = [&](const MatX& d3, double* out) {
    MatX d2(2 * N, d3.cols());
    for (int k = 0; k < N; ++k) d2.middleRows<2>(2 * k) = projection[k] * d3.middleRows<3>(3 * k);
    writeRowMajor(d2, out);
  };
  if (jacobians[0]) chain(d_pose, jacobians[0]);
  if (jacobians[1]) chain(d_betas, jacobians[1]);
  if (jacobians[2]) chain(d_trans, jacobians[2]);
  return true;
}

// ---------------------------------------------------------------------------------------------

PosePriorCost::PosePriorCost(double weight) {
  if (!(std::isfinite(weight) && weight >= 0.0))
    throw InputError("PosePriorCost: weight must be finite and ≥ 0, got " + std::to_string(weight));
  joint_weights_ = VecX::Constant(kNumJoints, weight);
  joint_weights_[0] = 0.0;
}

PosePriorCost::PosePriorCost(const VecX& joint_weights) {
  if (joint_weights.size() != kNumJoints)
    throw InputError("PosePriorCost: joint_weights has " + count(joint_weights.size()) +
                     " values, expected " + count(kNumJoints) + " (one per SMPL joint)");
  for (int b = 0; b < kNumJoints; ++b)
    if (!(std::isfinite(joint_weights[b]) && joint_weights[b] >= 0.0))
      throw InputError("PosePriorCost: joint_weights[" + count(b) +
                       "] must be finite and ≥ 0, got " + std::to_string(joint_weights[b]));
  joint_weights_ = joint_weights;
}

bool PosePriorCost::Evaluate(double const* const* parameters, double* residuals,
                             double** jacobians) const {
  if (!allFinite(parameters[0], kSmplPoseSize)) return false;
  for (int i = 0; i < kSmplPoseSize; ++i) residuals[i] = joint_weights_[i / 3] * parameters[0][i];
  if (jacobians && jacobians[0]) {
    Eigen::Map<RowMatX> J(jacobians[0], kSmplPoseSize, kSmplPoseSize);
    J.setZero();
    for (int i = 0; i < kSmplPoseSize; ++i) J(i, i) = joint_weights_[i / 3];
  }
  return true;
}

ShapePriorCost::ShapePriorCost(int num_betas, double weight) : weight_(weight) {
  if (num_betas < 1)
    throw InputError("ShapePriorCost: num_betas must be ≥ 1, got " + count(num_betas));
  if (!(std::isfinite(weight) && weight >= 0.0))
    throw InputError("ShapePriorCost: weight must be finite and ≥ 0, got " +
                     std::to_string(weight));
  set_num_residuals(num_betas);
  *mutable_parameter_block_sizes() = {num_betas};
}

bool ShapePriorCost::Evaluate(double const* const* parameters, double* residuals,
                              double** jacobians) const {
  const int n = num_residuals();
  if (!allFinite(parameters[0], n)) return false;
  for (int i = 0; i < n; ++i) residuals[i] = weight_ * parameters[0][i];
  if (jacobians && jacobians[0]) {
    Eigen::Map<RowMatX> J(jacobians[0], n, n);
    J.setZero();
    J.diagonal().setConstant(weight_);
  }
  return true;
}

}  // namespace flsh::ceres_costs
