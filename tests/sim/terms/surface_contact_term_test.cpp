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

// Shape has no setParameter (β is the avatar's), so its Jacobian is checked against the
// products here and against central differences over new avatars in parameter_derivatives_test.
TEST(SurfaceContactTerm, ShapeProductsAreNonzeroAndMatchTheJacobianForm) {
  auto sim = test::termScenario();
  const EnergyTerm& term = test::termNamed(*sim, kTerm);
  const int n = sim->numDofs(), k = sim->parameterSize(SimParameter::Shape);
  ParameterProducts<MatX> jac;
  jac[SimParameter::Shape] = MatX::Zero(n, k);
  term.addParameterJacobians(sim->termContext(), jac);
  const MatX& J = jac[SimParameter::Shape];
  ASSERT_GT(J.norm(), 0.0);
  const VecX lambda = test::randomVector(n, 1.0, 31);
  ParameterProducts<VecX> vjp;
  vjp[SimParameter::Shape] = VecX::Zero(k);
  term.addParameterProducts(sim->termContext(), lambda, vjp);
  EXPECT_LT((vjp[SimParameter::Shape] - J.transpose() * lambda).norm(),
            1e-10 * vjp[SimParameter::Shape].norm());
  const VecX dbeta = test::randomVector(k, 1.0, 32);
  ParameterDirection along{};
  along[size_t(SimParameter::Shape)] = &dbeta;
  std::vector<VecX> jvp(1, VecX::Zero(n));
  term.addParameterTangents(sim->termContext(), {along}, jvp);
  EXPECT_LT((jvp[0] - J * dbeta).norm(), 1e-10 * jvp[0].norm());
}

}  // namespace
}  // namespace flsh
