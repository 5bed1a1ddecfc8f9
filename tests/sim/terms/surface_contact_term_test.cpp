// Collider contact on the skinned surface alone against finite differences (a ground plane and
// a sphere, both touching). Its direct β products (the rest surface and areas) are checked with
// the whole gradient against rebuilt avatars (parameter_derivatives_test.cpp,
// ShapeMatchesRebuiltAvatars): β cannot be set on a built avatar.
#include "sim/terms/term_checks.h"

namespace flsh {
namespace {

constexpr const char* kTerm = "collider contact";

TEST(SurfaceContactTerm, DerivativesMatchFiniteDifferences) {
  auto sim = test::termScenario();
  ASSERT_GT(sim->termContext().contact.active, 1);
  test::expectTermDerivatives(*sim, test::termNamed(*sim, kTerm), 1e-5);
}

TEST(SurfaceContactTerm, ParameterProductsMatchFiniteDifferences) {
  auto sim = test::termScenario();
  const EnergyTerm& term = test::termNamed(*sim, kTerm);
  test::expectTermParameterProducts(*sim, term, SimParameter::RestJoints, 1e-5);
  test::expectTermParameterProducts(*sim, term, SimParameter::ColliderOffsets, 1e-5);
  test::expectTermParameterProducts(*sim, term, SimParameter::Stiffnesses, 1e-5, true);
  for (SimParameter p :
       {SimParameter::BoneInertia, SimParameter::PoseTargets, SimParameter::RootTranslationTarget})
    test::expectNoParameterProducts(*sim, term, p);
}

TEST(SurfaceContactTerm, ShapeProductsAreNonzeroAndMatchTheJacobianForm) {
  auto sim = test::termScenario();
  const EnergyTerm& term = test::termNamed(*sim, kTerm);
  const int n = sim->numDofs(), k = sim->parameterSize(SimParameter::Shape);
  ParameterProducts<MatX> jac;
  jac[SimParameter::Shape] = MatX::Zero(k, n);
  term.addParameterProducts(sim->termContext(), MatX(MatX::Identity(n, n)), jac);
  ASSERT_GT(jac[SimParameter::Shape].norm(), 0.0);
  const VecX lambda = test::randomVector(n, 1.0, 31);
  ParameterProducts<VecX> vjp;
  vjp[SimParameter::Shape] = VecX::Zero(k);
  term.addParameterProducts(sim->termContext(), lambda, vjp);
  EXPECT_LT((vjp[SimParameter::Shape] - jac[SimParameter::Shape] * lambda).norm(),
            1e-10 * vjp[SimParameter::Shape].norm());
}

}  // namespace
}  // namespace flsh
