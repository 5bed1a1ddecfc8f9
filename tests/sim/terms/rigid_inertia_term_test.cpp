// The rigid-inertia term alone against finite differences: gradient, exact Hessian, the bone
// inertia products and its previous-state derivatives.
#include "flsh/core/rotation.h"
#include "sim/terms/term_checks.h"

namespace flsh {
namespace {

constexpr const char* kTerm = "rigid inertia";

TEST(RigidInertiaTerm, DerivativesMatchFiniteDifferences) {
  auto sim = test::termScenario();
  test::expectTermDerivatives(*sim, test::termNamed(*sim, kTerm), 1e-5);
}

TEST(RigidInertiaTerm, BoneInertiaProductsMatchFiniteDifferences) {
  auto sim = test::termScenario();
  const EnergyTerm& term = test::termNamed(*sim, kTerm);
  test::expectTermParameterProducts(*sim, term, SimParameter::BoneInertia, 1e-5);
  for (SimParameter p : {SimParameter::RestJoints, SimParameter::PoseTargets,
                         SimParameter::Stiffnesses, SimParameter::ColliderOffsets})
    test::expectNoParameterProducts(*sim, term, p);
}

// ∂g/∂q_n and ∂g/∂q_{n−1} against central differences of the term's gradient when the previous
// states move along the chart; the products and the tangent are the same blocks.
TEST(RigidInertiaTerm, PreviousStatesMatchFiniteDifferences) {
  auto sim = test::termScenario();
  const EnergyTerm& term = test::termNamed(*sim, kTerm);
  ASSERT_TRUE(term.dependsOnPreviousStates());
  const int n = sim->numDofs();
  const SimulableStep step = sim->saveStep();
  const VecX q = sim->getState();
  for (int which : {1, 2}) {
    MatX D = MatX::Zero(n, n);
    term.addPreviousStateJacobian(sim->termContext(), which, D);
    ASSERT_GT(D.norm(), 0.0);
    const auto gradient = [&](const VecX& d) {
      // Move q_n (which = 1) or q_{n−1} (2) by the increments d.
      SimulableStep moved = step;
      Simulable& s = *sim;
      std::vector<Mat3>& R = which == 1 ? moved.R_n : moved.R_nm1;
      MatX3& t = which == 1 ? moved.t_n : moved.t_nm1;
      for (int b = 0; b < int(R.size()); ++b) {
        t.row(b) += d.segment<3>(6 * b).transpose();
        R[b] = rodrigues(d.segment<3>(6 * b + 3)) * R[b];
      }
      s.restoreStep(moved);
      return test::termGradient(s, term);
    };
    EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(gradient, VecX::Zero(n), D, 1e-5))
        << "which = " << which;
    sim->restoreStep(step);
    const VecX lambda = test::randomVector(n, 1.0, 21), dq = test::randomVector(n, 1.0, 22);
    VecX a_n = VecX::Zero(n), a_nm1 = VecX::Zero(n), tangent = VecX::Zero(n);
    term.addPreviousStatesProducts(sim->termContext(), lambda, &a_n, &a_nm1);
    term.addPreviousStatesTangent(sim->termContext(), which == 1 ? dq : VecX(VecX::Zero(n)),
                                  which == 2 ? dq : VecX(VecX::Zero(n)), tangent);
    EXPECT_LT(((which == 1 ? a_n : a_nm1) - D.transpose() * lambda).norm(), 1e-10 * a_n.norm());
    EXPECT_LT((tangent - D * dq).norm(), 1e-10 * tangent.norm());
  }
  EXPECT_EQ(sim->getState(), q);
}

TEST(RigidInertiaTerm, StaticIsZero) {
  auto sim = test::termScenario();
  sim->setStatic(true);
  const EnergyTerm& term = test::termNamed(*sim, kTerm);
  EXPECT_EQ(test::termEnergy(*sim, term), 0.0);
  EXPECT_EQ(test::termGradient(*sim, term).norm(), 0.0);
}

}  // namespace
}  // namespace flsh
