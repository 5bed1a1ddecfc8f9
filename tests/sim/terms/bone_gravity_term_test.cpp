// The bone-gravity term alone against finite differences.
#include "sim/terms/term_checks.h"

namespace flsh {
namespace {

constexpr const char* kTerm = "bone gravity";

TEST(BoneGravityTerm, DerivativesMatchFiniteDifferences) {
  auto sim = test::termScenario();
  test::expectTermDerivatives(*sim, test::termNamed(*sim, kTerm), 1e-5);
}

TEST(BoneGravityTerm, BoneInertiaProductsMatchFiniteDifferences) {
  auto sim = test::termScenario();
  const EnergyTerm& term = test::termNamed(*sim, kTerm);
  test::expectTermParameterProducts(*sim, term, SimParameter::BoneInertia, 1e-5);
  for (SimParameter p : {SimParameter::RestJoints, SimParameter::PoseTargets,
                         SimParameter::Stiffnesses, SimParameter::ColliderOffsets})
    test::expectNoParameterProducts(*sim, term, p);
}

}  // namespace
}  // namespace flsh
