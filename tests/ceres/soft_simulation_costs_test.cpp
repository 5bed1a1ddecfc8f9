// SimulationSequenceCost on the soft skeletons (FEM and ROM of the small body): the residuals are
// the simulated surface (soft tissue included) and the joints; the Jacobians of β, of material
// coefficients (named entries of MaterialModel::parameters(): the stiffness and the density) and
// of the initial velocity are nonzero and match central differences of re-run rollouts with
// ground contact and Ceres' GradientChecker; the adjoint's rows equal the forward sensitivities'
// (the surface of step 1 moves with q_0 through the pose blend); Ceres recovers a hidden β and
// soft-tissue stiffness from simulated observations; a Material block needs soft tissue and
// known names.
#include <ceres/problem.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "flsh/ceres/simulation_costs.h"
#include "flsh/core/error.h"
#include "support/ceres_cost_checks.h"
#include "support/small_soft_avatar.h"
#include "support/test_support.h"

namespace flsh::ceres_costs {
namespace {

using test::messageOf;
using test::pointersTo;
using test::randomVector;
using test::SoftModel;

constexpr int kSteps = 4;
using Blocks = std::vector<SequenceParameter>;

const test::SmallScene& scene() { return test::smallScene(800); }

// The soft tissue's stiffness along the fibre and its density. (The Fung exponent barely acts
// at the small body's strains: its column, ~1e-10 m, is below what differences of ~1 m
// residuals resolve.)
const std::vector<std::string> kMaterialNames{"layers.soft_tissue.E1.log_value",
                                              "layers.soft_tissue.density.log_value"};

// A ground plane 1 cm above the lowest surface node of the initial state: the walk presses in.
std::vector<Collider> ground(SoftModel model) {
  Simulable sim(test::smallSoftAvatar(model), scene().walk);
  sim.initialize();
  return {Collider::plane(Vec3(0, sim.getNodes().col(1).minCoeff() + 0.01, 0), Vec3::UnitY())};
}

SimulationCostOptions tightOptions(
    SequenceJacobians method = SequenceJacobians::ForwardSensitivities) {
  SimulationCostOptions o;
  for (NewtonOptions* newton : {&o.rollout.soft_tissue_newton, &o.rollout.reduced_newton}) {
    newton->gradient_tolerance = 1e-11;  // the Jacobians are exact for the converged rollout
    newton->max_iterations = 100;
  }
  o.jacobians = method;
  o.num_betas = 2;
  o.material_names = kMaterialNames;
  return o;
}

// Two joints and surface vertices over the body against random points (the residuals are not
// zero, as in a fit far from the optimum).
SequenceObservations someObservations(int steps) {
  SequenceObservations obs;
  obs.joints = {0, 18};
  obs.vertices = {5, 222, 431, 700};
  const VecX values = randomVector(steps * 3 * obs.numPoints(), 1.0, 7);
  obs.observed = Eigen::Map<const RowMatX>(values.data(), steps, 3 * obs.numPoints());
  obs.step_weights = VecX::LinSpaced(steps, 0.5, 2.0);
  return obs;
}

std::unique_ptr<SimulationSequenceCost> makeCost(
    SoftModel model, const Blocks& blocks, int steps = kSteps,
    const SimulationCostOptions& options = tightOptions()) {
  return std::make_unique<SimulationSequenceCost>(test::smallSoftAvatar(model), scene().walk,
                                                  SimulableOptions(), ground(model), steps,
                                                  someObservations(steps), blocks, options);
}

// Values near the defaults: β moved, the stiffness 1.3× and the density 0.8×.
std::vector<VecX> valuesNearDefaults(const SimulationSequenceCost& cost) {
  std::vector<VecX> values;
  for (SequenceParameter p : cost.blocks()) {
    VecX v = cost.defaultValue(p);
    if (p == SequenceParameter::Shape) v += Eigen::Vector2d(0.4, -0.3);
    if (p == SequenceParameter::Material) v += Eigen::Vector2d(std::log(1.3), std::log(0.8));
    if (p == SequenceParameter::InitialVelocity) v += randomVector(int(v.size()), 0.05, 3);
    values.push_back(v);
  }
  return values;
}

class SoftSimulationSequenceCost : public ::testing::TestWithParam<SoftModel> {};

TEST_P(SoftSimulationSequenceCost, ResidualsAreTheSimulatedSurfaceAndJoints) {
  const SoftModel model = GetParam();
  const auto cost = makeCost(model, {SequenceParameter::Material});
  const VecX material = cost->defaultValue(SequenceParameter::Material);
  ASSERT_EQ(material.size(), 2);
  const double* params[] = {material.data()};
  VecX r(cost->num_residuals());
  ASSERT_TRUE(cost->Evaluate(params, r.data(), nullptr));

  auto sim = std::make_shared<Simulable>(test::smallSoftAvatar(model), scene().walk);
  sim->setColliders(ground(model));
  Rollout rollout(sim, tightOptions().rollout);
  rollout.run(kSteps);
  const SequenceObservations obs = someObservations(kSteps);
  const RowMatX joints = rollout.joints();
  for (int t = 0; t < kSteps; ++t) {
    const MatX3 vertices = rollout.vertices(t + 1);
    for (int k = 0; k < obs.numPoints(); ++k) {
      const bool joint = k < int(obs.joints.size());
      const Vec3 x = joint ? Vec3(joints.row(t).segment<3>(3 * obs.joints[k]).transpose())
                           : Vec3(vertices.row(obs.vertices[k - obs.joints.size()]).transpose());
      const Vec3 expected =
          obs.step_weights[t] * (x - obs.observed.row(t).segment<3>(3 * k).transpose());
      EXPECT_TRUE(r.segment<3>(t * 3 * obs.numPoints() + 3 * k).isApprox(expected, 1e-9))
          << "step " << t + 1 << " point " << k;
    }
  }
  // The surface is not the skinned bones: the tissue moves it.
  EXPECT_GT(sim->getSoftTissueDisplacements().cwiseAbs().maxCoeff(), 1e-5);
}

// β and two material coefficients: the whole blocks against central differences (1e-6 of the
// largest entry for the ROM, 1e-5 for the FEM), and entry-wise by Ceres' GradientChecker.
TEST_P(SoftSimulationSequenceCost, ShapeAndMaterialJacobiansPassGradientChecker) {
  const SoftModel model = GetParam();
  const auto cost = makeCost(model, {SequenceParameter::Shape, SequenceParameter::Material});
  ASSERT_EQ(cost->parameter_block_sizes(), (std::vector<int32_t>{2, 2}));
  const std::vector<VecX> values = valuesNearDefaults(*cost);
  EXPECT_TRUE(test::matchesCentralDifferences(*cost, pointersTo(values),
                                              model == SoftModel::Fem ? 1e-5 : 1e-6));
  EXPECT_TRUE(
      test::passesGradientChecker(*cost, pointersTo(values), 1e-3, test::contactDiffOptions()));
}

TEST_P(SoftSimulationSequenceCost, AdjointJacobiansEqualForwardSensitivities) {
  const SoftModel model = GetParam();
  const Blocks blocks{SequenceParameter::Material, SequenceParameter::Shape,
                      SequenceParameter::InitialVelocity};
  const auto forward = makeCost(model, blocks, 2);
  const auto adjoint = makeCost(model, blocks, 2, tightOptions(SequenceJacobians::Adjoint));
  const std::vector<VecX> values = valuesNearDefaults(*forward);
  EXPECT_TRUE(test::sameJacobians(*forward, *adjoint, pointersTo(values), 1e-8));
}

// Observations simulated at a hidden β and a 1.5× stiffer soft tissue; Ceres recovers both from
// the base avatar's values.
TEST_P(SoftSimulationSequenceCost, CeresRecoversShapeAndStiffness) {
  const SoftModel model = GetParam();
  SimulationCostOptions options = tightOptions();
  options.material_names = {kMaterialNames[0]};
  const Blocks blocks{SequenceParameter::Shape, SequenceParameter::Material};
  const auto probe = makeCost(model, blocks, kSteps, options);
  const VecX true_betas =
      probe->defaultValue(SequenceParameter::Shape) + Eigen::Vector2d(0.6, -0.5);
  const VecX true_material =
      probe->defaultValue(SequenceParameter::Material) + VecX::Constant(1, std::log(1.5));
  const double* truth[] = {true_betas.data(), true_material.data()};
  SequenceObservations obs = someObservations(kSteps);
  obs.observed = probe->simulate(truth);

  SimulationSequenceCost cost(test::smallSoftAvatar(model), scene().walk, SimulableOptions(),
                              ground(model), kSteps, obs, blocks, options);
  VecX betas = cost.defaultValue(SequenceParameter::Shape);
  VecX material = cost.defaultValue(SequenceParameter::Material);
  ceres::Problem::Options problem_options;
  problem_options.cost_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  problem.AddResidualBlock(&cost, nullptr, betas.data(), material.data());
  const ceres::Solver::Summary summary = test::solveTightly(problem);
  EXPECT_TRUE(summary.IsSolutionUsable()) << summary.BriefReport();
  EXPECT_LT(summary.final_cost, 1e-14) << summary.BriefReport();
  EXPECT_LT((betas - true_betas).cwiseAbs().maxCoeff(), 1e-4) << betas.transpose();
  EXPECT_LT(std::abs(material[0] - true_material[0]), 1e-3) << material.transpose();
}

INSTANTIATE_TEST_SUITE_P(Models, SoftSimulationSequenceCost,
                         ::testing::Values(SoftModel::Fem, SoftModel::Rom), test::modelName);

TEST(SoftSimulationSequenceCostErrors, MaterialNeedsSoftTissueAndKnownNames) {
  const SequenceObservations obs = someObservations(kSteps);
  const Blocks material{SequenceParameter::Material};
  EXPECT_NE(messageOf<InputError>([&] {
              SimulationSequenceCost(test::smallScene(800).avatar, scene().walk, SimulableOptions(),
                                     {}, kSteps, obs, material);
            }).find("no soft tissue"),
            std::string::npos);
  SimulationCostOptions options = tightOptions();
  options.material_names = {"layers.soft_tissue.E7.log_value"};
  EXPECT_NE(messageOf<InputError>([&] {
              SimulationSequenceCost(test::smallSoftAvatar(SoftModel::Rom), scene().walk,
                                     SimulableOptions(), {}, kSteps, obs, material, options);
            }).find("material_names[0] = 'layers.soft_tissue.E7.log_value' is not"),
            std::string::npos);
  options.material_names = {kMaterialNames[0], kMaterialNames[0]};
  EXPECT_NE(messageOf<InputError>([&] {
              SimulationSequenceCost(test::smallSoftAvatar(SoftModel::Rom), scene().walk,
                                     SimulableOptions(), {}, kSteps, obs, material, options);
            }).find("twice"),
            std::string::npos);
}

}  // namespace
}  // namespace flsh::ceres_costs
