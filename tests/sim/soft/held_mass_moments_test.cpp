// The nodal inertia's and gravity's bone-only forms from the mass nodes' moments at held unposed
// positions (sim/soft/held_mass_moments.h; the bones' presolve) against the node sums they
// replace, and against central differences; and the Simulable's bone-only evaluation, which
// defers the ROM's skinning, against its whole gradient and Hessian. FEM and ROM.
#include "flsh/core/rotation.h"
#include "sim/soft/soft_term_checks.h"

namespace flsh {
namespace {

using test::atMovedState;
using test::jacobianMatchesFiniteDifferences;
using test::pullBackRotationGradient;
using test::randomVector;
using test::SoftModel;

class HeldMassMoments : public ::testing::TestWithParam<SoftModel> {};

MatX denseWithBlocks(std::vector<Triplet> H, const std::vector<FixedHessianBlocks>& blocks, int n) {
  for (const Triplet& t : test::expanded(blocks)) H.push_back(t);
  return test::denseFromTriplets(H, n);
}

TermContext boneOnly(const Simulable& sim) {
  TermContext c = sim.termContext();
  c.bone_block_only = true;
  return c;
}

// The bone-only form (moments) against the node sums, i.e. the term's whole evaluation (its node
// loop, whose derivatives the terms' own tests check by differences): energy, bone rows (the
// soft rows untouched) and the bone–bone Hessian blocks, exact and PSD.
void expectMomentsMatchNodeSums(const Simulable& sim, const char* when) {
  const int n = sim.numDofs(), nb = sim.numBoneDofs();
  const TermContext c = boneOnly(sim);
  for (const char* name : {"nodal inertia", "nodal gravity"}) {
    const EnergyTerm& term = test::termNamed(sim, name);
    SCOPED_TRACE(std::string(name) + ", " + when);
    VecX g_nodes = VecX::Zero(n), g_moments = VecX::Zero(n);
    const double E_nodes = term.evaluate(sim.termContext(), &g_nodes, 0);
    const double E_moments = term.evaluate(c, &g_moments, 0);
    ASSERT_GT(g_nodes.head(nb).norm(), 0.0);
    EXPECT_NEAR(E_moments, E_nodes, 1e-10 * (1.0 + std::abs(E_nodes)));
    EXPECT_LE((g_moments - g_nodes).head(nb).norm(), 1e-9 * g_nodes.head(nb).norm());
    EXPECT_EQ(g_moments.tail(n - nb).norm(), 0.0) << "the soft rows are left alone";
    for (bool psd : {false, true}) {
      std::vector<Triplet> moments_triplets;
      term.addHessian(c, moments_triplets, 0, psd);
      const MatX H_moments = test::denseFromTriplets(moments_triplets, n);
      const MatX H_nodes = test::softTermHessian(sim, term, psd);
      ASSERT_GT(H_nodes.topLeftCorner(nb, nb).norm(), 0.0) << "psd " << psd;
      EXPECT_LE((H_moments.topLeftCorner(nb, nb) - H_nodes.topLeftCorner(nb, nb)).norm(),
                1e-9 * H_nodes.topLeftCorner(nb, nb).norm())
          << "psd " << psd;
      EXPECT_EQ(H_moments.rightCols(n - nb).norm() + H_moments.bottomRows(n - nb).norm(), 0.0)
          << "psd " << psd;
    }
  }
}

TEST_P(HeldMassMoments, MatchTheNodeSumsAsBonesSoftStateAndPredictionMove) {
  auto sim = test::softTermScenario(GetParam());
  const int n = sim->numDofs(), nb = sim->numBoneDofs();
  expectMomentsMatchNodeSums(*sim, "at the scenario's state");
  // The bones alone (the moments stay; the reference frames are now 2–4 cm and degrees away).
  VecX d = VecX::Zero(n);
  d.head(nb) = randomVector(nb, 0.04, 21);
  sim->updateState(d);
  expectMomentsMatchNodeSums(*sim, "after moving the bones");
  // The soft state (the unposed positions change: the moments follow).
  d.setZero();
  d.tail(n - nb) = randomVector(n - nb, 0.003, 22);
  sim->updateState(d);
  expectMomentsMatchNodeSums(*sim, "after moving the soft state");
  // A new step: new prediction and held pose blend.
  sim->postUpdate();
  sim->preUpdate();
  d.setZero();
  d.head(nb) = randomVector(nb, 0.02, 23);
  sim->updateState(d);
  expectMomentsMatchNodeSums(*sim, "a step later");
}

// The bone-only forms' own derivatives by central differences along the bones (the moments
// held: the soft state does not move).
TEST_P(HeldMassMoments, BoneOnlyDerivativesMatchFiniteDifferences) {
  auto sim = test::softTermScenario(GetParam());
  const int n = sim->numDofs(), nb = sim->numBoneDofs();
  for (const char* name : {"nodal inertia", "nodal gravity"}) {
    SCOPED_TRACE(name);
    const EnergyTerm& term = test::termNamed(*sim, name);
    VecX g = VecX::Zero(n);
    term.evaluate(boneOnly(*sim), &g, 0);
    std::vector<Triplet> triplets;
    term.addHessian(boneOnly(*sim), triplets, 0, false);
    const MatX H = test::denseFromTriplets(triplets, n).topLeftCorner(nb, nb);
    ASSERT_GT(g.head(nb).norm(), 0.0);
    ASSERT_GT(H.norm(), 0.0);
    const auto expand = [&](const VecX& sub) {
      VecX d = VecX::Zero(n);
      d.head(nb) = sub;
      return d;
    };
    const auto energy = [&](const VecX& sub) {
      return atMovedState(*sim, expand(sub), [&] {
        return VecX::Constant(1, term.evaluate(boneOnly(*sim), nullptr, 0));
      });
    };
    const auto gradient = [&](const VecX& sub) {
      return atMovedState(*sim, expand(sub), [&] {
        VecX gd = VecX::Zero(n);
        term.evaluate(boneOnly(*sim), &gd, 0);
        return VecX(pullBackRotationGradient(gd, expand(sub)).head(nb));
      });
    };
    const VecX zero = VecX::Zero(nb);
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(energy, zero, g.head(nb).transpose(), 1e-5));
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, zero, H, 1e-5));
  }
}

// Simulable's bone-only evaluation (the presolve's: the ROM defers its skinning) equals the
// whole gradient's bone rows and the whole Hessian's bone block — also as the first evaluation
// of a step (new prediction and pose blend, nothing skinned since) and right after the bones
// move, and the whole evaluation after it still sees the current state.
TEST_P(HeldMassMoments, SimulableBoneOnlyEvaluationMatchesTheWholeOne) {
  auto sim = test::softTermScenario(GetParam());
  const int n = sim->numDofs(), nb = sim->numBoneDofs();
  const auto compare = [&](const char* when) {
    SCOPED_TRACE(when);
    VecX g_bones = VecX::Zero(n);
    sim->getBoneEnergyAndGradientVector(g_bones);
    std::vector<Triplet> bone_triplets;
    std::vector<FixedHessianBlocks> bone_blocks;
    sim->getBoneHessianTripletVector(bone_triplets, bone_blocks, 0, false);
    const MatX H_bones = denseWithBlocks(bone_triplets, bone_blocks, n);
    const VecX g = test::totalGradient(*sim);
    std::vector<Triplet> triplets;
    std::vector<FixedHessianBlocks> blocks;
    sim->getHessianTripletVector(triplets, blocks, 0, false);
    const MatX H = denseWithBlocks(triplets, blocks, n);
    ASSERT_GT(g.head(nb).norm(), 0.0);
    EXPECT_LE((g_bones - g).head(nb).norm(), 1e-9 * g.head(nb).norm());
    EXPECT_LE((H_bones - H).topLeftCorner(nb, nb).norm(), 1e-9 * H.topLeftCorner(nb, nb).norm());
  };
  compare("at the scenario's state");
  sim->postUpdate();
  sim->preUpdate();
  compare("first evaluation of a step");
  VecX d = VecX::Zero(n);
  d.head(nb) = randomVector(nb, 0.03, 31);
  sim->updateState(d);
  VecX g_bones = VecX::Zero(n);
  sim->getBoneEnergyAndGradientVector(g_bones);  // deferred skinning at the moved bones
  compare("after moving the bones");
  d.setZero();
  d.tail(n - nb) = randomVector(n - nb, 0.002, 32);
  sim->updateState(d);
  compare("after moving the soft state");
}

INSTANTIATE_TEST_SUITE_P(Models, HeldMassMoments,
                         ::testing::Values(SoftModel::Fem, SoftModel::Rom, SoftModel::RomModes),
                         test::modelName);

}  // namespace
}  // namespace flsh
