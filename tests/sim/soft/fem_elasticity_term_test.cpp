// The FEM soft skeleton's elastic energy alone against finite differences.
#include "sim/soft/soft_term_checks.h"

namespace flsh {
namespace {

using test::SoftModel;

TEST(FemElasticityTerm, DerivativesMatchFiniteDifferences) {
  auto sim = test::softTermScenario(SoftModel::Fem);
  ASSERT_FALSE(sim->hasReducedModel());
  // Reads u alone (the tissue's deformation in the unposed frame): no bone rows.
  test::expectSoftTermDerivatives(*sim, test::termNamed(*sim, "elasticity"), true, false);
}

// Zero energy and gradient at rest (u = 0) whatever the bones do.
TEST(FemElasticityTerm, RestIsStressFreeInAnyPose) {
  auto sim = test::softTermScenario(SoftModel::Fem);
  VecX q = sim->getState();
  q.tail(sim->numDofs() - sim->numBoneDofs()).setZero();
  sim->setState(q);
  const EnergyTerm& term = test::termNamed(*sim, "elasticity");
  const VecX g = test::termGradient(*sim, term);
  EXPECT_EQ(term.evaluate(sim->termContext(), nullptr, 0), 0.0);
  EXPECT_EQ(g.norm(), 0.0);
}

}  // namespace
}  // namespace flsh
