// Collider contact on the soft skeletons' surface nodes alone against finite differences (FEM
// and ROM).
#include "sim/soft/soft_term_checks.h"

namespace flsh {
namespace {

using test::SoftModel;

class NodeContactTerm : public ::testing::TestWithParam<SoftModel> {};

TEST_P(NodeContactTerm, DerivativesMatchFiniteDifferences) {
  auto sim = test::softTermScenario(GetParam());
  const EnergyTerm& term = test::termNamed(*sim, "node contact");
  ASSERT_GT(term.evaluate(sim->termContext(), nullptr, 0), 0.0) << "no node in contact";
  test::expectSoftTermDerivatives(*sim, term, true, true);
}

// ∂g/∂p of the contact stiffness, the collider offsets and the rest joints against central
// differences of the term's gradient under setParameter, reaching bones and soft DoFs (FEM: the
// node's own u; ROM: its basis row's handles); the VJP and the JVP against the Jacobian; nothing
// for the groups the term does not depend on.
TEST_P(NodeContactTerm, ParameterProductsMatchFiniteDifferences) {
  auto sim = test::softTermScenario(GetParam());
  const EnergyTerm& term = test::termNamed(*sim, "node contact");
  test::expectTermParameterProducts(*sim, term, SimParameter::ColliderOffsets, 1e-5);
  test::expectTermParameterProducts(*sim, term, SimParameter::Stiffnesses, 1e-5, true);
  test::expectTermParameterProducts(*sim, term, SimParameter::RestJoints, 1e-5);
  ParameterProducts<MatX> jac;
  const int n = sim->numDofs(), nb = sim->numBoneDofs();
  jac[SimParameter::ColliderOffsets] =
      MatX::Zero(n, sim->parameterSize(SimParameter::ColliderOffsets));
  term.addParameterJacobians(sim->termContext(), jac);
  EXPECT_GT(jac[SimParameter::ColliderOffsets].bottomRows(n - nb).norm(), 0.0)
      << "the offsets move the soft DoFs too";
  for (SimParameter p :
       {SimParameter::BoneInertia, SimParameter::PoseTargets, SimParameter::RootTranslationTarget})
    test::expectNoParameterProducts(*sim, term, p);
}

// The broad phase only drops nodes out of contact: the energy the simulable's broad phase
// evaluated over its candidates (what the term returns for the energy alone) equals the term
// evaluated over every surface node; without colliders it is zero.
TEST_P(NodeContactTerm, CandidatesGiveTheSameEnergyAsEveryNode) {
  auto sim = test::softTermScenario(GetParam());
  const EnergyTerm& term = test::termNamed(*sim, "node contact");
  const TermContext c = sim->termContext();
  const size_t surface = size_t(sim->avatar().restVertices().rows());
  ASSERT_LT(c.contact.candidates.size(), surface);
  const double E = term.evaluate(c, nullptr, 0);
  SurfaceContactState all;
  all.candidates.resize(surface);
  for (size_t i = 0; i < surface; ++i) all.candidates[i] = int(i);
  const TermContext every{c.num_bones,  c.parents,    c.J,          c.inertia,   c.options,
                          c.tracking,   c.is_static,  c.R,          c.t,         c.R_n,
                          c.t_n,        c.R_nm1,      c.t_nm1,      c.target_R,  c.target_t0,
                          c.tracking_k, c.root_k_pos, c.root_k_rot, c.colliders, c.time,
                          c.avatar,     c.skin,       all};
  ASSERT_GT(E, 0.0);
  VecX g_candidates = VecX::Zero(sim->numDofs()), g_every = VecX::Zero(sim->numDofs());
  EXPECT_NEAR(term.evaluate(c, &g_candidates, 0), E, 1e-12 * E);
  EXPECT_NEAR(term.evaluate(every, &g_every, 0), E, 1e-12 * E);
  EXPECT_LT((g_every - g_candidates).norm(), 1e-12 * g_every.norm());
  sim->setColliders({});
  EXPECT_EQ(term.evaluate(sim->termContext(), nullptr, 0), 0.0);
}

INSTANTIATE_TEST_SUITE_P(Models, NodeContactTerm,
                         ::testing::Values(SoftModel::Fem, SoftModel::Rom, SoftModel::RomModes),
                         test::modelName);

}  // namespace
}  // namespace flsh
