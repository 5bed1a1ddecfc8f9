// The soft skeletons' nodal inertia alone against finite differences (FEM and ROM).
#include "sim/soft/soft_term_checks.h"

namespace flsh {
namespace {

using test::SoftModel;

class NodalInertiaTerm : public ::testing::TestWithParam<SoftModel> {};

TEST_P(NodalInertiaTerm, DerivativesMatchFiniteDifferences) {
  auto sim = test::softTermScenario(GetParam());
  test::expectSoftTermDerivatives(*sim, test::termNamed(*sim, "nodal inertia"), true, true);
}

// The energy is ½ Σ m_j ‖x_j − x̂_j‖² / h²: zero at the prediction x̂ = 2 x_n − x_{n−1}, which the
// state q = 2 q_n − q_{n−1} reaches exactly when the bones do not turn (here: a pure
// translation history of the whole body and the soft state).
TEST_P(NodalInertiaTerm, VanishesAtThePredictionOfAUniformMotion) {
  auto sim = std::make_unique<Simulable>(test::smallSoftAvatar(GetParam()));
  sim->initialize();
  const int n = sim->numDofs(), nb = sim->numBoneDofs();
  VecX step = VecX::Zero(n);
  for (int b = 0; b < nb / 6; ++b) step.segment<3>(6 * b) = Vec3(0.01, -0.02, 0.005);
  step.tail(n - nb) = test::randomVector(n - nb, 0.001, 9);
  sim->preUpdate();
  sim->updateState(step);
  sim->postUpdate();
  sim->preUpdate();  // the state starts at the prediction 2 q_n − q_{n−1}
  const EnergyTerm& term = test::termNamed(*sim, "nodal inertia");
  const double E = term.evaluate(sim->termContext(), nullptr, 0);
  sim->updateState(step);
  const double moved = term.evaluate(sim->termContext(), nullptr, 0);
  ASSERT_GT(moved, 0.0);
  EXPECT_LT(E, 1e-12 * moved);
}

// ∂g/∂J (the nodes' skinning at q, in the prediction x̂ = 2 x(q_n) − x(q_{n−1}), and the lever
// arms) against central differences of the term's gradient under setParameter(RestJoints),
// which predicts again; nothing for the groups it does not depend on.
TEST_P(NodalInertiaTerm, RestJointProductsMatchFiniteDifferences) {
  auto sim = test::softTermScenario(GetParam());
  const EnergyTerm& term = test::termNamed(*sim, "nodal inertia");
  test::expectTermParameterProducts(*sim, term, SimParameter::RestJoints, 1e-5);
  for (SimParameter p : {SimParameter::Stiffnesses, SimParameter::ColliderOffsets,
                         SimParameter::PoseTargets, SimParameter::BoneInertia})
    test::expectNoParameterProducts(*sim, term, p);
}

// The term's dense previous-state blocks (EnergyTerm::addPreviousStateJacobian): for q_{n−1},
// which only the prediction x̂ reads, the whole simulable's (tested against differences in
// soft_previous_state_derivatives_test.cpp); for q_n, its products.
TEST_P(NodalInertiaTerm, PreviousStateBlocksMatchTheSimulablesAndTheProducts) {
  auto sim = test::softTermScenario(GetParam());
  const EnergyTerm& term = test::termNamed(*sim, "nodal inertia");
  const int n = sim->numDofs();
  MatX D[2] = {MatX::Zero(n, n), MatX::Zero(n, n)};
  for (int which : {1, 2}) term.addPreviousStateJacobian(sim->termContext(), which, D[which - 1]);
  ASSERT_GT(D[1].norm(), 0.0);
  const MatX whole = sim->getGradientPreviousStateJacobian(2);
  EXPECT_LT((D[1] - whole).norm(), 1e-12 * whole.norm());
  const VecX lambda = test::randomVector(n, 1.0, 71);
  VecX a_n = VecX::Zero(n);
  term.addPreviousStatesProducts(sim->termContext(), lambda, &a_n, nullptr);
  ASSERT_GT(D[0].norm(), 0.0);
  EXPECT_LT((a_n - D[0].transpose() * lambda).norm(), 1e-10 * a_n.norm());
}

INSTANTIATE_TEST_SUITE_P(Models, NodalInertiaTerm,
                         ::testing::Values(SoftModel::Fem, SoftModel::Rom, SoftModel::RomModes),
                         test::modelName);

}  // namespace
}  // namespace flsh
