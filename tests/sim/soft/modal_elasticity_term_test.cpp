// The ROM's elastic energy on a basis with modes beyond what it shares with the handle basis
// (reduced_elasticity_term_test.cpp: derivatives, rest stiffness): the adjoint's Material and
// Shape groups, not built for modes yet, are refused with a clear error, never wrong numbers.
#include "flsh/core/error.h"
#include "sim/soft/soft_term_checks.h"

namespace flsh {
namespace {

using test::SoftModel;

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
