// The soft skeletons' nodal gravity alone against finite differences (FEM and ROM).
#include "sim/soft/soft_term_checks.h"

namespace flsh {
namespace {

using test::SoftModel;

class NodalGravityTerm : public ::testing::TestWithParam<SoftModel> {};

TEST_P(NodalGravityTerm, DerivativesMatchFiniteDifferences) {
  auto sim = test::softTermScenario(GetParam());
  // Linear in the node positions, which are linear in u: no soft–soft blocks.
  test::expectSoftTermDerivatives(*sim, test::termNamed(*sim, "nodal gravity"), false, true);
}

// −Σ m_j g · x_j: lifting the whole body by d changes it by −M g · d, M the mass of the nodes
// (every node's lumped mass, or the inertial cubature's, which keeps the total mass).
TEST_P(NodalGravityTerm, LiftingTheBodyCostsItsWeight) {
  auto sim = test::softTermScenario(GetParam());
  const EnergyTerm& term = test::termNamed(*sim, "nodal gravity");
  const double E0 = term.evaluate(sim->termContext(), nullptr, 0);
  const int n = sim->numDofs(), nb = sim->numBoneDofs();
  VecX lift = VecX::Zero(n);
  for (int b = 0; b < nb / 6; ++b) lift[6 * b + 1] = 0.1;
  sim->updateState(lift);
  const double E1 = term.evaluate(sim->termContext(), nullptr, 0);
  const Vec3 g = sim->options().gravity;
  ASSERT_LT(g.y(), 0.0);
  const double mass = (E1 - E0) / (-g.y() * 0.1);
  EXPECT_GT(mass, 0.0);
  EXPECT_NEAR(mass, sim->avatar().volumetricData().totalMass(), 0.05 * mass);
}

// ∂g/∂J (the lever arms of the rotation rows) against central differences of the term's
// gradient under setParameter(RestJoints); nothing for the groups it does not depend on.
TEST_P(NodalGravityTerm, RestJointProductsMatchFiniteDifferences) {
  auto sim = test::softTermScenario(GetParam());
  const EnergyTerm& term = test::termNamed(*sim, "nodal gravity");
  test::expectTermParameterProducts(*sim, term, SimParameter::RestJoints, 1e-5);
  for (SimParameter p : {SimParameter::Stiffnesses, SimParameter::ColliderOffsets,
                         SimParameter::PoseTargets, SimParameter::BoneInertia})
    test::expectNoParameterProducts(*sim, term, p);
}

INSTANTIATE_TEST_SUITE_P(Models, NodalGravityTerm,
                         ::testing::Values(SoftModel::Fem, SoftModel::Rom, SoftModel::RomModes),
                         test::modelName);

}  // namespace
}  // namespace flsh
