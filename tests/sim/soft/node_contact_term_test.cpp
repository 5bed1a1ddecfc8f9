// Collider contact on the soft skeletons' surface nodes alone against finite differences (FEM
// and ROM).
#include "sim/soft/soft_term_checks.h"

namespace flsh {
namespace {

using test::SoftModel;

class NodeContactTerm : public ::testing::TestWithParam<SoftModel> {};

TEST_P(NodeContactTerm, DerivativesMatchFiniteDifferences) {
  auto sim = test::softTermScenario(GetParam());
  const EnergyTerm& term = test::softTermNamed(*sim, "node contact");
  ASSERT_GT(term.evaluate(sim->termContext(), nullptr, 0), 0.0) << "no node in contact";
  test::expectSoftTermDerivatives(*sim, term, true, true);
}

// The broad phase only drops nodes out of contact: the term over its candidates equals the term
// over every surface node (no colliders: zero).
TEST_P(NodeContactTerm, CandidatesGiveTheSameEnergyAsEveryNode) {
  auto sim = test::softTermScenario(GetParam());
  const EnergyTerm& term = test::softTermNamed(*sim, "node contact");
  const TermContext c = sim->termContext();
  ASSERT_LT(c.contact.candidates.size(), size_t(sim->avatar().restVertices().rows()));
  const double E = term.evaluate(c, nullptr, 0);
  SurfaceContactState all;
  all.candidates.resize(size_t(sim->avatar().restVertices().rows()));
  for (size_t i = 0; i < all.candidates.size(); ++i) all.candidates[i] = int(i);
  const TermContext every{c.num_bones,  c.parents,    c.J,          c.inertia,   c.options,
                          c.tracking,   c.is_static,  c.R,          c.t,         c.R_n,
                          c.t_n,        c.R_nm1,      c.t_nm1,      c.target_R,  c.target_t0,
                          c.tracking_k, c.root_k_pos, c.root_k_rot, c.colliders, c.time,
                          c.avatar,     c.skin,       all};
  ASSERT_GT(E, 0.0);
  EXPECT_NEAR(term.evaluate(every, nullptr, 0), E, 1e-12 * E);
  sim->setColliders({});
  EXPECT_EQ(term.evaluate(sim->termContext(), nullptr, 0), 0.0);
}

INSTANTIATE_TEST_SUITE_P(Models, NodeContactTerm, ::testing::Values(SoftModel::Fem, SoftModel::Rom),
                         test::modelName);

}  // namespace
}  // namespace flsh
