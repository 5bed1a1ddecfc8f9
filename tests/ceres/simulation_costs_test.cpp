// SimulationSequenceCost: residuals against the rollout's own joints and skinned vertices;
// Jacobians (forward sensitivities and adjoint) of every block kind, after requiring them to be
// nonzero, against central differences of re-run rollouts with ground contact and against Ceres'
// GradientChecker; the two Jacobian methods agree; Ceres solves recover the shape β and the
// root's initial velocity from simulated observations; construction errors and failing
// evaluations.
#include "flsh/ceres/simulation_costs.h"

#include <ceres/dynamic_numeric_diff_cost_function.h>
#include <ceres/gradient_checker.h>
#include <ceres/manifold.h>
#include <ceres/problem.h>
#include <ceres/solver.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <vector>

#include "flsh/core/error.h"
#include "support/ceres_cost_checks.h"
#include "support/test_support.h"

namespace flsh::ceres_costs {
namespace {

using test::contactDiffOptions;
using test::jacobiansOf;
using test::matchesCentralDifferences;
using test::messageOf;
using test::passesGradientChecker;
using test::pointersTo;
using test::randomVector;

constexpr int kSteps = 6;

const test::SmallScene& scene() { return test::smallScene(600, 1.0); }

// A ground plane 1 cm above the lowest vertex of the initial pose: the walk presses into it.
std::vector<Collider> ground() {
  Simulable sim(scene().avatar, scene().walk);
  sim.initialize();
  return {Collider::plane(Vec3(0, sim.getNodes().col(1).minCoeff() + 0.01, 0), Vec3::UnitY())};
}

SimulationCostOptions tightOptions(
    SequenceJacobians method = SequenceJacobians::ForwardSensitivities, int num_betas = 3) {
  SimulationCostOptions o;
  o.rollout.newton.gradient_tolerance = 1e-12;  // Jacobians are exact for the converged rollout
  o.jacobians = method;
  o.num_betas = num_betas;
  return o;
}

// Joints across the tree and vertices spread over the surface; observations are random points
// in a 2 m cube about the origin (the residuals are then not zero, as in a fit far from the
// optimum).
SequenceObservations someObservations(int steps) {
  SequenceObservations obs;
  obs.joints = {0, 4, 7, 10, 15, 20};
  obs.vertices = {3, 150, 333, 512};
  const VecX values = randomVector(steps * 3 * obs.numPoints(), 1.0, 99);
  obs.observed = Eigen::Map<const RowMatX>(values.data(), steps, 3 * obs.numPoints());
  obs.step_weights = VecX::LinSpaced(steps, 0.5, 2.0);
  return obs;
}

using Blocks = std::vector<SequenceParameter>;

// The cost over `steps` steps of the walk, on the ground (or without colliders).
std::unique_ptr<SimulationSequenceCost> makeCost(
    const Blocks& blocks, int steps = kSteps, const SimulationCostOptions& options = tightOptions(),
    bool with_ground = true) {
  return std::make_unique<SimulationSequenceCost>(scene().avatar, scene().walk, SimulableOptions(),
                                                  with_ground ? ground() : std::vector<Collider>(),
                                                  steps, someObservations(steps), blocks, options);
}

// Parameter values near the defaults (a perturbed β, velocity and targets), one vector per block.
std::vector<VecX> valuesNearDefaults(const SimulationSequenceCost& cost, unsigned seed) {
  std::vector<VecX> values;
  for (SequenceParameter p : cost.blocks()) {
    VecX v = cost.defaultValue(p);
    if (p == SequenceParameter::Shape) v += randomVector(int(v.size()), 0.5, seed);
    if (p == SequenceParameter::InitialVelocity) v += randomVector(int(v.size()), 0.1, seed + 1);
    if (p == SequenceParameter::PoseTargets) v += randomVector(int(v.size()), 0.05, seed + 2);
    values.push_back(v);
  }
  return values;
}

TEST(SimulationSequenceCost, ResidualsAreWeightedRolloutPointsMinusObservations) {
  const auto cost = makeCost({SequenceParameter::Stiffnesses});
  const VecX stiffnesses = cost->defaultValue(SequenceParameter::Stiffnesses);
  const SequenceObservations obs = someObservations(kSteps);
  const double* params[] = {stiffnesses.data()};
  VecX r(cost->num_residuals());
  ASSERT_EQ(r.size(), kSteps * 3 * obs.numPoints());
  ASSERT_TRUE(cost->Evaluate(params, r.data(), nullptr));

  auto sim = std::make_shared<Simulable>(scene().avatar, scene().walk);
  sim->setColliders(ground());
  Rollout rollout(sim, tightOptions().rollout);
  rollout.run(kSteps);
  const RowMatX joints = rollout.joints();
  const int nj = int(obs.joints.size());
  for (int t = 0; t < kSteps; ++t) {
    const MatX3 vertices = rollout.vertices(t + 1);
    for (int k = 0; k < obs.numPoints(); ++k) {
      const Vec3 x = k < nj ? Vec3(joints.row(t).segment<3>(3 * obs.joints[k]).transpose())
                            : Vec3(vertices.row(obs.vertices[k - nj]).transpose());
      const Vec3 expected =
          obs.step_weights[t] * (x - obs.observed.row(t).segment<3>(3 * k).transpose());
      EXPECT_TRUE(r.segment<3>(t * 3 * obs.numPoints() + 3 * k).isApprox(expected, 1e-9))
          << "step " << t + 1 << " point " << k;
    }
  }
}

TEST(SimulationSequenceCost, ShapeAndStiffnessJacobiansPassGradientChecker) {
  const auto cost = makeCost({SequenceParameter::Shape, SequenceParameter::Stiffnesses});
  ASSERT_EQ(cost->parameter_block_sizes(), (std::vector<int32_t>{3, 4}));
  const std::vector<VecX> values = valuesNearDefaults(*cost, 11);
  EXPECT_TRUE(matchesCentralDifferences(*cost, pointersTo(values)));
  EXPECT_TRUE(passesGradientChecker(*cost, pointersTo(values), 1e-3, contactDiffOptions()));
}

TEST(SimulationSequenceCost, InitialVelocityJacobiansPassGradientChecker) {
  const std::vector<int32_t> sizes{144};
  const auto cost = makeCost({SequenceParameter::InitialVelocity}, 3);
  ASSERT_EQ(cost->parameter_block_sizes(), sizes);
  const std::vector<VecX> values = valuesNearDefaults(*cost, 12);
  EXPECT_TRUE(matchesCentralDifferences(*cost, pointersTo(values)));
  // Entry-wise without the ground, with Ceres' default (most accurate) Ridders steps: entries
  // down to 1e-14 here.
  const auto free = makeCost({SequenceParameter::InitialVelocity}, 3, tightOptions(), false);
  EXPECT_TRUE(passesGradientChecker(*free, pointersTo(values), 5e-2));
}

TEST(SimulationSequenceCost, PoseTargetJacobiansPassGradientChecker) {
  const int steps = 2;  // 144 target columns, each numeric column several rollouts
  for (SequenceJacobians method :
       {SequenceJacobians::ForwardSensitivities, SequenceJacobians::Adjoint}) {
    const auto cost = makeCost({SequenceParameter::PoseTargets}, steps, tightOptions(method));
    ASSERT_EQ(cost->parameter_block_sizes(), (std::vector<int32_t>{72 * steps}));
    const std::vector<VecX> values = valuesNearDefaults(*cost, 21);
    EXPECT_TRUE(matchesCentralDifferences(*cost, pointersTo(values))) << "method " << int(method);
    EXPECT_TRUE(passesGradientChecker(*cost, pointersTo(values), 1e-2, contactDiffOptions()))
        << "method " << int(method);
  }
}

TEST(SimulationSequenceCost, AdjointJacobiansEqualForwardSensitivities) {
  const Blocks blocks{SequenceParameter::InitialVelocity, SequenceParameter::Shape,
                      SequenceParameter::Stiffnesses, SequenceParameter::PoseTargets};
  const auto forward = makeCost(blocks, 4, tightOptions(SequenceJacobians::ForwardSensitivities));
  const auto adjoint = makeCost(blocks, 4, tightOptions(SequenceJacobians::Adjoint));
  const std::vector<VecX> values = valuesNearDefaults(*forward, 31);
  EXPECT_TRUE(test::sameJacobians(*forward, *adjoint, pointersTo(values), 1e-9));
}

TEST(SimulationSequenceCost, ConstantBlocksAreSkipped) {
  const auto cost = makeCost({SequenceParameter::Shape, SequenceParameter::InitialVelocity});
  const std::vector<VecX> values = valuesNearDefaults(*cost, 41);
  const std::vector<RowMatX> all = jacobiansOf(*cost, pointersTo(values));
  RowMatX velocity(cost->num_residuals(), 144);
  double* jacobians[] = {nullptr, velocity.data()};
  VecX r(cost->num_residuals());
  ASSERT_TRUE(cost->Evaluate(pointersTo(values).data(), r.data(), jacobians));
  EXPECT_TRUE(velocity.isApprox(all[1], 1e-12));
}

// Observations simulated at a true β; Ceres recovers it from the base avatar's β.
TEST(SimulationSequenceCost, CeresRecoversShape) {
  const Blocks blocks{SequenceParameter::Shape};
  const auto probe = makeCost(blocks);
  const VecX true_betas = probe->defaultValue(SequenceParameter::Shape) + Vec3(0.8, -0.6, 0.4);
  const double* truth[] = {true_betas.data()};
  SequenceObservations obs = someObservations(kSteps);
  obs.observed = probe->simulate(truth);

  SimulationSequenceCost cost(scene().avatar, scene().walk, SimulableOptions(), ground(), kSteps,
                              obs, blocks, tightOptions());
  VecX betas = cost.defaultValue(SequenceParameter::Shape);
  ASSERT_GT((betas - true_betas).norm(), 0.5);
  ceres::Problem::Options problem_options;
  problem_options.cost_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  problem.AddResidualBlock(&cost, nullptr, betas.data());
  const ceres::Solver::Summary summary = test::solveTightly(problem);
  EXPECT_TRUE(summary.IsSolutionUsable()) << summary.BriefReport();
  EXPECT_LT(summary.final_cost, 1e-16) << summary.BriefReport();
  EXPECT_LT((betas - true_betas).cwiseAbs().maxCoeff(), 1e-6) << betas.transpose();
}

// The root's initial velocity (6 of the 144 values; the others held by a SubsetManifold: the
// velocities of a bone relative to its parent are damped out by the stiff joint springs within
// a step and barely observable) recovered from a sequence simulated with another root velocity.
TEST(SimulationSequenceCost, CeresRecoversRootInitialVelocity) {
  const Blocks blocks{SequenceParameter::InitialVelocity};
  const auto probe = makeCost(blocks);
  const VecX start = probe->defaultValue(SequenceParameter::InitialVelocity);
  VecX true_velocity = start;
  true_velocity.head<6>() += Eigen::Matrix<double, 6, 1>(0.3, -0.2, 0.25, 0.5, -0.4, 0.3);
  const double* truth[] = {true_velocity.data()};
  SequenceObservations obs = someObservations(kSteps);
  obs.observed = probe->simulate(truth);

  SimulationSequenceCost cost(scene().avatar, scene().walk, SimulableOptions(), ground(), kSteps,
                              obs, blocks, tightOptions());
  VecX velocity = start;
  std::vector<int> held;
  for (int i = 6; i < 144; ++i) held.push_back(i);
  ceres::SubsetManifold root_only(144, held);
  ceres::Problem::Options problem_options;
  problem_options.cost_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  problem.AddResidualBlock(&cost, nullptr, velocity.data());
  problem.SetManifold(velocity.data(), &root_only);
  const ceres::Solver::Summary summary = test::solveTightly(problem);
  EXPECT_TRUE(summary.IsSolutionUsable()) << summary.BriefReport();
  EXPECT_LT(summary.final_cost, 1e-16) << summary.BriefReport();
  EXPECT_LT((velocity - true_velocity).cwiseAbs().maxCoeff(), 1e-6)
      << velocity.head<6>().transpose();
}

TEST(SimulationSequenceCost, EvaluateFailsWithoutThrowingOnBadParameters) {
  const auto cost = makeCost({SequenceParameter::Stiffnesses, SequenceParameter::Shape});
  VecX stiffnesses = cost->defaultValue(SequenceParameter::Stiffnesses);
  VecX betas = cost->defaultValue(SequenceParameter::Shape);
  const double* params[] = {stiffnesses.data(), betas.data()};
  VecX r(cost->num_residuals());
  ASSERT_TRUE(cost->Evaluate(params, r.data(), nullptr));
  betas[1] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(cost->Evaluate(params, r.data(), nullptr));
  betas[1] = 0.0;
  stiffnesses[0] = -1.0;  // a negative joint stiffness: the rollout refuses it
  EXPECT_FALSE(cost->Evaluate(params, r.data(), nullptr));
  EXPECT_THROW(cost->simulate(params), InputError);
}

TEST(SimulationSequenceCost, EvaluateFailsWhenNewtonDoesNotConverge) {
  SimulationCostOptions options = tightOptions();
  options.rollout.newton.max_iterations = 1;  // cannot reach 1e-12 in one iteration
  const auto cost = makeCost({SequenceParameter::Stiffnesses}, kSteps, options);
  const VecX stiffnesses = cost->defaultValue(SequenceParameter::Stiffnesses);
  const double* params[] = {stiffnesses.data()};
  VecX r(cost->num_residuals());
  EXPECT_FALSE(cost->Evaluate(params, r.data(), nullptr));
  EXPECT_THROW(cost->simulate(params), Error);
}

TEST(SimulationSequenceCost, ConstructionErrorsNameTheArgument) {
  const auto make = [](SequenceObservations obs, Blocks blocks,
                       std::shared_ptr<const Motion> mocap = scene().walk, int steps = kSteps,
                       SimulationCostOptions options = tightOptions()) {
    SimulationSequenceCost(scene().avatar, mocap, SimulableOptions(), ground(), steps,
                           std::move(obs), std::move(blocks), options);
  };
  const Blocks shape{SequenceParameter::Shape};
  SequenceObservations obs = someObservations(kSteps);
  EXPECT_NE(messageOf<InputError>([&] { make(obs, {}); }).find("blocks is empty"),
            std::string::npos);
  EXPECT_NE(messageOf<InputError>([&] {
              make(obs, {SequenceParameter::Shape, SequenceParameter::Shape});
            }).find("Shape twice"),
            std::string::npos);
  EXPECT_NE(messageOf<InputError>([&] {
              make(obs, {SequenceParameter::PoseTargets}, nullptr);
            }).find("PoseTargets"),
            std::string::npos);
  EXPECT_NE(messageOf<InputError>([&] { make(obs, shape, scene().walk, 0); }).find("steps = 0"),
            std::string::npos);
  SimulationCostOptions too_many = tightOptions();
  too_many.num_betas = 11;
  EXPECT_NE(messageOf<InputError>([&] {
              make(obs, shape, scene().walk, kSteps, too_many);
            }).find("num_betas = 11, expected 1..10"),
            std::string::npos);

  SequenceObservations bad = obs;
  bad.joints[2] = 24;
  EXPECT_NE(messageOf<InputError>([&] { make(bad, shape); }).find("joints[2] = 24, expected 0..23"),
            std::string::npos);
  bad = obs;
  bad.vertices[0] = 600;
  EXPECT_NE(
      messageOf<InputError>([&] { make(bad, shape); }).find("vertices[0] = 600, expected 0..599"),
      std::string::npos);
  bad = obs;
  bad.observed = RowMatX::Zero(kSteps - 1, 30);
  EXPECT_NE(messageOf<InputError>([&] {
              make(bad, shape);
            }).find("observed has shape (5, 30), expected (6, 30)"),
            std::string::npos);
  bad = obs;
  bad.observed(2, 4) = std::numeric_limits<double>::infinity();
  EXPECT_NE(messageOf<InputError>([&] { make(bad, shape); }).find("NaN or Inf"), std::string::npos);
  bad = obs;
  bad.step_weights[3] = -1.0;
  EXPECT_NE(messageOf<InputError>([&] { make(bad, shape); }).find("step_weights[3]"),
            std::string::npos);
  bad = obs;
  bad.joints.clear();
  bad.vertices.clear();
  EXPECT_NE(messageOf<InputError>([&] { make(bad, shape); }).find("no joint and no vertex"),
            std::string::npos);
  EXPECT_NE(messageOf<InputError>([&] {
              SimulationSequenceCost(nullptr, scene().walk, SimulableOptions(), {}, kSteps, obs,
                                     shape);
            }).find("avatar is null"),
            std::string::npos);
}

}  // namespace
}  // namespace flsh::ceres_costs
