// The ROM soft skeleton's elastic energy (subspace, elastic cubature, rest-stiffness split)
// alone against finite differences, on the handle basis (ReducedElasticityTerm) and on modes
// with handles (ModalElasticityTerm).
#include "sim/soft/soft_term_checks.h"

namespace flsh {
namespace {

using test::SoftModel;

class ReducedElasticityTerm : public ::testing::TestWithParam<SoftModel> {};

TEST_P(ReducedElasticityTerm, DerivativesMatchFiniteDifferences) {
  auto sim = test::softTermScenario(GetParam());
  ASSERT_TRUE(sim->hasReducedModel());
  if (GetParam() == SoftModel::RomModes) {
    ASSERT_GT(sim->avatar().reducedData().numModes(), 0);
    ASSERT_GT(sim->avatar().reducedData().numHandles(), 0);
  }
  test::expectSoftTermDerivatives(*sim, test::termNamed(*sim, "elasticity"), true, false);
}

// The split keeps the exact rest stiffness K of the subspace: near z = 0 the energy is ½ zᵀ K z
// with K positive definite, so it grows quadratically in every direction.
TEST_P(ReducedElasticityTerm, GrowsQuadraticallyFromRest) {
  auto sim = test::softTermScenario(GetParam());
  const int n = sim->numDofs(), nb = sim->numBoneDofs();
  const EnergyTerm& term = test::termNamed(*sim, "elasticity");
  VecX q = sim->getState();
  const VecX direction = test::randomVector(n - nb, 1.0, 21);
  const auto energyAt = [&](double s) {
    q.tail(n - nb) = s * direction;
    sim->setState(q);
    return term.evaluate(sim->termContext(), nullptr, 0);
  };
  EXPECT_EQ(energyAt(0.0), 0.0);
  const double small = energyAt(1e-5), twice = energyAt(2e-5);
  ASSERT_GT(small, 0.0);
  EXPECT_NEAR(twice / small, 4.0, 1e-3);
}

INSTANTIATE_TEST_SUITE_P(Bases, ReducedElasticityTerm,
                         ::testing::Values(SoftModel::Rom, SoftModel::RomModes), test::modelName);

}  // namespace
}  // namespace flsh
