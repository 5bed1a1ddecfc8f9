// The joint-spring term alone against finite differences.
#include "sim/terms/term_checks.h"

namespace flsh {
namespace {

constexpr const char* kTerm = "joint springs";

TEST(JointSpringTerm, DerivativesMatchFiniteDifferences) {
  auto sim = test::termScenario();
  test::expectTermDerivatives(*sim, test::termNamed(*sim, kTerm), 1e-5);
}

TEST(JointSpringTerm, ParameterProductsMatchFiniteDifferences) {
  auto sim = test::termScenario();
  const EnergyTerm& term = test::termNamed(*sim, kTerm);
  test::expectTermParameterProducts(*sim, term, SimParameter::RestJoints, 1e-5);
  test::expectTermParameterProducts(*sim, term, SimParameter::Stiffnesses, 1e-5, true);
  for (SimParameter p : {SimParameter::BoneInertia, SimParameter::PoseTargets,
                         SimParameter::RootTranslationTarget, SimParameter::ColliderOffsets})
    test::expectNoParameterProducts(*sim, term, p);
}

}  // namespace
}  // namespace flsh
