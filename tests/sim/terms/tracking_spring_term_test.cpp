// The tracking and root springs alone against finite differences, through the stiffnesses'
// dependence on the rest joints and bone inertias.
#include "sim/terms/term_checks.h"

namespace flsh {
namespace {

constexpr const char* kTerm = "tracking and root springs";

TEST(TrackingSpringTerm, DerivativesMatchFiniteDifferences) {
  auto sim = test::termScenario();
  test::expectTermDerivatives(*sim, test::termNamed(*sim, kTerm), 1e-5);
}

TEST(TrackingSpringTerm, ParameterProductsMatchFiniteDifferences) {
  auto sim = test::termScenario();
  const EnergyTerm& term = test::termNamed(*sim, kTerm);
  for (SimParameter p : {SimParameter::RestJoints, SimParameter::BoneInertia,
                         SimParameter::PoseTargets, SimParameter::RootTranslationTarget})
    test::expectTermParameterProducts(*sim, term, p, 1e-5);
  test::expectTermParameterProducts(*sim, term, SimParameter::Stiffnesses, 1e-5, true);
  test::expectNoParameterProducts(*sim, term, SimParameter::ColliderOffsets);
}

TEST(TrackingSpringTerm, OffWithoutTracking) {
  const test::SmallScene& scene = test::smallScene(600, 1.0);
  SimulableOptions options;
  options.track_mocap = false;
  Simulable sim(scene.avatar, scene.walk, options);
  sim.initialize();
  const EnergyTerm& term = test::termNamed(sim, kTerm);
  EXPECT_EQ(test::termEnergy(sim, term), 0.0);
  EXPECT_EQ(test::termGradient(sim, term).norm(), 0.0);
}

}  // namespace
}  // namespace flsh
