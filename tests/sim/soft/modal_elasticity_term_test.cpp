// The ROM soft skeleton's elastic energy on a basis with modes (modes and handles, elastic
// cubature, rest-stiffness split) alone against finite differences.
#include "flsh/core/error.h"
#include "sim/soft/soft_term_checks.h"

namespace flsh {
namespace {

using test::SoftModel;

TEST(ModalElasticityTerm, DerivativesMatchFiniteDifferences) {
  auto sim = test::softTermScenario(SoftModel::RomModes);
  ASSERT_TRUE(sim->hasReducedModel());
  ASSERT_GT(sim->avatar().reducedData().numModes(), 0);
  ASSERT_GT(sim->avatar().reducedData().numHandles(), 0);
  test::expectSoftTermDerivatives(*sim, test::termNamed(*sim, "elasticity"), true, false);
}

// The split keeps the exact rest stiffness K of the subspace: near z = 0 the energy is ½ zᵀ K z
// with K positive definite, so it grows quadratically in every direction, modes and handles.
TEST(ModalElasticityTerm, GrowsQuadraticallyFromRest) {
  auto sim = test::softTermScenario(SoftModel::RomModes);
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

// The adjoint's Material and Shape groups are not built for modes yet: a clear error, no wrong
// numbers.
TEST(ModalElasticityTerm, ParameterGroupsAreRefusedClearly) {
  auto sim = test::softTermScenario(SoftModel::RomModes);
  for (SimParameter group : {SimParameter::Material, SimParameter::Shape}) {
    ASSERT_GT(sim->parameterSize(group), 0);
    try {
      sim->getGradientParameterJacobian(group);
      FAIL() << "expected InputError";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("not available yet"), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace flsh
