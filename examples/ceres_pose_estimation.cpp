// Workflow 1: SMPL pose and shape estimation with Ceres (flsh/ceres/smpl_costs.h) on the full
// 6890-vertex synthetic body. A known random-but-plausible pose, shape and translation make
// synthetic observations of 24 joints and 72 surface markers (3 per bone); then
//   1. 3D keypoints with Gaussian noise σ = 5 mm,
//   2. 2D keypoints with σ = 1.5 px in two pinhole cameras (front and side, 1000 px focal
//      length, 3.5 m away),
// are fitted from the zero pose, β = 0, trans = 0 (with weak pose and shape priors), and the
// recovered joints, vertices and bone rotations are compared with the truth.
//
//   ./build/bin/example_ceres_pose_estimation [vertices]
#include <ceres/ceres.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <memory>
#include <random>
#include <vector>

#include "flsh/body/body_forward.h"
#include "flsh/body/smpl_skeleton.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/ceres/smpl_costs.h"
#include "flsh/core/rotation.h"

using namespace flsh;
using namespace flsh::ceres_costs;

namespace {

constexpr double kPi = 3.14159265358979323846;

VecX uniform(int n, double scale, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-scale, scale);
  VecX v(n);
  for (int i = 0; i < n; ++i) v[i] = u(rng);
  return v;
}

void report(const char* name, const BodyModel& model, const PosedBody& truth, const VecX& pose,
            const VecX& betas, const Vec3& trans, const ceres::Solver::Summary& summary,
            double seconds) {
  const PosedBody estimate = poseBody(model, betas, pose, trans);
  const double joint_error = (estimate.joints - truth.joints).rowwise().norm().mean();
  const double vertex_error = (estimate.vertices - truth.vertices).rowwise().norm().mean();
  std::vector<double> angles;
  for (int j = 0; j < kNumJoints; ++j)
    angles.push_back(logSO3(Mat3(estimate.transforms[j].topLeftCorner<3, 3>()).transpose() *
                            truth.transforms[j].topLeftCorner<3, 3>())
                         .norm());
  std::sort(angles.begin(), angles.end());
  std::printf(
      "%s\n  mean joint error   %.2f mm\n  mean vertex error  %.2f mm\n"
      "  bone rotation error median %.2f deg, max %.2f deg\n"
      "  %d iterations, %s, %.3f s\n",
      name, 1e3 * joint_error, 1e3 * vertex_error, angles[angles.size() / 2] * 180 / kPi,
      angles.back() * 180 / kPi, int(summary.iterations.size()),
      ceres::TerminationTypeToString(summary.termination_type), seconds);
}

ceres::Solver::Summary solve(ceres::Problem& problem, double& seconds) {
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::DENSE_QR;
  options.max_num_iterations = 200;
  options.function_tolerance = 1e-12;
  options.gradient_tolerance = 1e-12;
  options.parameter_tolerance = 1e-12;
  ceres::Solver::Summary summary;
  const auto start = std::chrono::steady_clock::now();
  ceres::Solve(options, &problem, &summary);
  seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

}  // namespace

int main(int argc, char** argv) {
  SyntheticBodyOptions body_options;
  if (argc > 1) body_options.vertices = std::atoi(argv[1]);
  try {
    const auto model = std::make_shared<const BodyModel>(makeSyntheticBody(body_options));
    const int K = model->numBetas();

    // Ground truth: body joints within ±0.35 rad per axis, a turned root, β within ±1.
    std::mt19937 rng(2024);
    VecX true_pose = uniform(72, 0.35, rng);
    true_pose.head<3>() << 0.1, 0.5, -0.05;
    const VecX true_betas = uniform(K, 1.0, rng);
    const Vec3 true_trans(0.15, 0.05, -0.2);
    const PosedBody truth = poseBody(*model, true_betas, true_pose, true_trans);
    const KeypointSelection sel = KeypointSelection::jointsAndMarkers(*model, 3);
    const MatX3 points = sel.pick(truth);
    std::printf("body: %d vertices, %d shape components; %d keypoints (24 joints, %zu markers)\n",
                model->numVertices(), K, sel.size(), sel.vertices.size());

    // 1. 3D keypoints, σ = 5 mm.
    {
      std::normal_distribution<double> noise(0.0, 0.005);
      MatX3 observed = points;
      for (int i = 0; i < observed.size(); ++i) observed.data()[i] += noise(rng);
      VecX pose = VecX::Zero(72), betas = VecX::Zero(K);
      Vec3 trans = Vec3::Zero();
      ceres::Problem problem;
      problem.AddResidualBlock(new SmplKeypoints3dCost(model, sel, observed), nullptr, pose.data(),
                               betas.data(), trans.data());
      problem.AddResidualBlock(new PosePriorCost(0.005), nullptr, pose.data());
      problem.AddResidualBlock(new ShapePriorCost(K, 0.005), nullptr, betas.data());
      double seconds = 0;
      const ceres::Solver::Summary summary = solve(problem, seconds);
      report("3D keypoints (sigma = 5 mm):", *model, truth, pose, betas, trans, summary, seconds);
    }

    // 2. 2D keypoints in two cameras, σ = 1.5 px.
    {
      const Vec3 centre(0.0, 0.9, 0.0);
      const std::vector<PinholeCamera> cameras = {
          PinholeCamera::lookAt(centre + Vec3(0.0, 0.3, 3.5), centre, Vec3::UnitY(), 1000.0, 1000.0,
                                500.0, 500.0),
          PinholeCamera::lookAt(centre + Vec3(3.5, 0.2, 0.5), centre, Vec3::UnitY(), 1000.0, 1000.0,
                                500.0, 500.0)};
      std::normal_distribution<double> noise(0.0, 1.5);
      VecX pose = VecX::Zero(72), betas = VecX::Zero(K);
      Vec3 trans = Vec3::Zero();
      ceres::Problem problem;
      for (const PinholeCamera& camera : cameras) {
        MatX2 observed(sel.size(), 2);
        for (int k = 0; k < sel.size(); ++k)
          observed.row(k) =
              (camera.project(points.row(k).transpose()) + Vec2(noise(rng), noise(rng)))
                  .transpose();
        problem.AddResidualBlock(new SmplKeypoints2dCost(model, sel, camera, observed), nullptr,
                                 pose.data(), betas.data(), trans.data());
      }
      problem.AddResidualBlock(new PosePriorCost(2.0), nullptr, pose.data());  // px per rad
      problem.AddResidualBlock(new ShapePriorCost(K, 2.0), nullptr, betas.data());
      double seconds = 0;
      const ceres::Solver::Summary summary = solve(problem, seconds);
      report("2D keypoints, two cameras (sigma = 1.5 px):", *model, truth, pose, betas, trans,
             summary, seconds);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
  return 0;
}
