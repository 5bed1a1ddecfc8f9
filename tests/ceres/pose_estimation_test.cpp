// Workflow 1: SMPL pose (and shape) estimation with Ceres on an 800-vertex synthetic body from
// a known random-but-plausible pose and shape:
//  - exact 3D keypoints (24 joints + 72 surface markers, 3 per bone), solved from the zero
//    pose: the truth to 1 µm and 1e-5 rad;
//  - noisy 3D keypoints (same points, σ = 5 mm): mean 3D joint error < 1 cm, mean vertex error
//    < 1 cm, median global bone rotation error < 6°;
//  - noisy 2D keypoints (same points, σ = 1.5 px) in two pinhole cameras (front and side,
//    1000 px focal length, 3.5 m away) with pose and shape priors: mean 3D joint error < 1 cm,
//    mean vertex error < 1.5 cm.
#include <ceres/ceres.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <random>
#include <vector>

#include "flsh/body/body_forward.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/ceres/smpl_costs.h"
#include "flsh/core/rotation.h"
#include "support/ceres_cost_checks.h"
#include "support/test_support.h"

namespace flsh::ceres_costs {
namespace {

constexpr double kPi = 3.14159265358979323846;

struct Truth {
  VecX pose, betas;
  Vec3 trans;
  PosedBody posed;
};

// Joint limits of a plausible pose: ±0.35 rad per axis on body joints, a turned root.
Truth makeTruth(const BodyModel& body) {
  Truth t;
  t.pose = test::randomVector(72, 0.35, 42);
  t.pose.head<3>() << 0.1, 0.5, -0.05;
  t.betas = test::randomVector(body.numBetas(), 1.0, 43);
  t.trans = Vec3(0.15, 0.05, -0.2);
  t.posed = poseBody(body, t.betas, t.pose, t.trans);
  return t;
}

double meanRowDistance(const MatX3& a, const MatX3& b) { return (a - b).rowwise().norm().mean(); }

// Median over joints of the angle (rad) between estimated and true global bone rotations.
double medianRotationError(const PosedBody& estimate, const PosedBody& truth) {
  std::vector<double> angles;
  for (int j = 0; j < kNumJoints; ++j) {
    const Mat3 Re = estimate.transforms[j].topLeftCorner<3, 3>();
    const Mat3 Rt = truth.transforms[j].topLeftCorner<3, 3>();
    angles.push_back(logSO3(Re.transpose() * Rt).norm());
  }
  std::nth_element(angles.begin(), angles.begin() + angles.size() / 2, angles.end());
  return angles[angles.size() / 2];
}

// 200 iterations to 1e-12: the keypoint fits start far from the truth.
ceres::Solver::Summary solve(ceres::Problem& problem) {
  return test::solveTightly(problem, 200, 1e-12);
}

std::shared_ptr<const BodyModel> body() {
  static const auto b = std::make_shared<const BodyModel>(makeSyntheticBody({800, 1.70}));
  return b;
}

struct FitErrors {
  double joint = 0, vertex = 0, rotation = 0;  // mean m, mean m, median rad
  int iterations = 0;
};

// Fits θ, β, trans from the zero pose to the 24 joints and 72 markers of the truth, each with
// Gaussian noise of `sigma` (m), with pose and shape priors of weight `prior` (m per rad, m per
// unit β).
FitErrors fit3d(double sigma, double prior) {
  const auto model = body();
  const Truth truth = makeTruth(*model);
  const KeypointSelection sel = KeypointSelection::jointsAndMarkers(*model, 3);
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 1.0);
  MatX3 observed = sel.pick(truth.posed);
  for (int i = 0; i < observed.size(); ++i) observed.data()[i] += sigma * noise(rng);

  VecX pose = VecX::Zero(72), betas = VecX::Zero(model->numBetas());
  Vec3 trans = Vec3::Zero();
  ceres::Problem problem;
  problem.AddResidualBlock(new SmplKeypoints3dCost(model, sel, observed), nullptr, pose.data(),
                           betas.data(), trans.data());
  problem.AddResidualBlock(new PosePriorCost(prior), nullptr, pose.data());
  problem.AddResidualBlock(new ShapePriorCost(model->numBetas(), prior), nullptr, betas.data());
  const ceres::Solver::Summary summary = solve(problem);
  EXPECT_TRUE(summary.IsSolutionUsable()) << summary.FullReport();

  const PosedBody estimate = poseBody(*model, betas, pose, trans);
  FitErrors e;
  e.joint = meanRowDistance(estimate.joints, truth.posed.joints);
  e.vertex = meanRowDistance(estimate.vertices, truth.posed.vertices);
  e.rotation = medianRotationError(estimate, truth.posed);
  e.iterations = int(summary.iterations.size());
  // The zero pose started far away: the fit did real work.
  const PosedBody start = poseBody(*model, VecX::Zero(10), VecX::Zero(72));
  EXPECT_GT(meanRowDistance(start.joints, truth.posed.joints), 0.1);
  return e;
}

TEST(PoseEstimation, From3dKeypointsWithoutNoiseRecoversTheTruth) {
  // A vanishing prior: the keypoints alone determine the pose and shape.
  const FitErrors e = fit3d(0.0, 1e-8);
  EXPECT_LT(e.joint, 1e-6);
  EXPECT_LT(e.vertex, 1e-6);
  EXPECT_LT(e.rotation, 1e-5);
}

TEST(PoseEstimation, From3dKeypointsWithNoise) {
  // σ = 5 mm; weak priors (1 rad of pose or 1 unit of β costs as much as a 5 mm offset) keep
  // the directions that few keypoints see (twist of end bones) near rest.
  const FitErrors e = fit3d(0.005, 0.005);
  EXPECT_LT(e.joint, 0.01);
  EXPECT_LT(e.vertex, 0.01);
  EXPECT_LT(e.rotation, 6.0 * kPi / 180.0);
  std::printf(
      "3D fit (σ = 5 mm): mean joint error %.2f mm, mean vertex error %.2f mm, median "
      "bone rotation error %.2f deg, %d iterations\n",
      1e3 * e.joint, 1e3 * e.vertex, e.rotation * 180.0 / kPi, e.iterations);
}

TEST(PoseEstimation, From2dKeypointsInTwoCamerasWithNoise) {
  const auto model = body();
  const Truth truth = makeTruth(*model);
  const KeypointSelection sel = KeypointSelection::jointsAndMarkers(*model, 3);
  const MatX3 points = sel.pick(truth.posed);
  const Vec3 centre(0.0, 0.9, 0.0);
  const std::vector<PinholeCamera> cameras = {
      PinholeCamera::lookAt(centre + Vec3(0.0, 0.3, 3.5), centre, Vec3::UnitY(), 1000.0, 1000.0,
                            500.0, 500.0),
      PinholeCamera::lookAt(centre + Vec3(3.5, 0.2, 0.5), centre, Vec3::UnitY(), 1000.0, 1000.0,
                            500.0, 500.0)};
  std::mt19937 rng(8);
  std::normal_distribution<double> noise(0.0, 1.5);  // σ = 1.5 px

  VecX pose = VecX::Zero(72), betas = VecX::Zero(model->numBetas());
  Vec3 trans = Vec3::Zero();
  ceres::Problem problem;
  for (const PinholeCamera& camera : cameras) {
    MatX2 observed(sel.size(), 2);
    for (int k = 0; k < sel.size(); ++k)
      observed.row(k) =
          (camera.project(points.row(k).transpose()) + Vec2(noise(rng), noise(rng))).transpose();
    problem.AddResidualBlock(new SmplKeypoints2dCost(model, sel, camera, observed), nullptr,
                             pose.data(), betas.data(), trans.data());
  }
  // Priors in px: 1 rad of joint rotation costs like a 2 px offset, 1 unit of β like 2 px.
  problem.AddResidualBlock(new PosePriorCost(2.0), nullptr, pose.data());
  problem.AddResidualBlock(new ShapePriorCost(model->numBetas(), 2.0), nullptr, betas.data());
  const ceres::Solver::Summary summary = solve(problem);
  ASSERT_TRUE(summary.IsSolutionUsable()) << summary.FullReport();

  const PosedBody estimate = poseBody(*model, betas, pose, trans);
  const double joint_error = meanRowDistance(estimate.joints, truth.posed.joints);
  const double vertex_error = meanRowDistance(estimate.vertices, truth.posed.vertices);
  EXPECT_LT(joint_error, 0.01) << summary.BriefReport();
  EXPECT_LT(vertex_error, 0.015) << summary.BriefReport();
  std::printf(
      "2D fit (2 cameras, σ = 1.5 px): mean joint error %.2f mm, mean vertex error "
      "%.2f mm, median bone rotation error %.2f deg, %d iterations\n",
      1e3 * joint_error, 1e3 * vertex_error,
      medianRotationError(estimate, truth.posed) * 180.0 / kPi, int(summary.iterations.size()));
}

}  // namespace
}  // namespace flsh::ceres_costs
