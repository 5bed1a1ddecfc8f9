// Finite-difference checks shared by the soft skeletons' node terms (tests/sim/soft/*_test.cpp):
// each term alone (Simulable::energyTerms, the EnergyTerm interface) at a moved state of a small
// FEM or ROM soft avatar. Every check first asserts the analytic quantity is nonzero.
#pragma once

#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <memory>
#include <numeric>
#include <random>
#include <stdexcept>
#include <string>

#include "flsh/core/rotation.h"
#include "flsh/sim/simulable.h"
#include "sim/terms/term_checks.h"
#include "support/small_soft_avatar.h"
#include "support/test_support.h"

namespace flsh::test {

/// A walking soft avatar one step in with a velocity history (bones and soft state), moved off
/// its prediction, a ground plane 1.5 cm above its lowest node and a sphere pressing into its
/// frontmost node: every node term is active.
inline std::unique_ptr<Simulable> softTermScenario(std::shared_ptr<const SoftAvatar> avatar) {
  auto sim = std::make_unique<Simulable>(std::move(avatar), smallScene(800).walk);
  sim->initialize();
  sim->preUpdate();
  const int n = sim->numDofs(), nb = sim->numBoneDofs();
  const auto increment = [&](double bones, double soft, unsigned seed) {
    VecX d = randomVector(n, 1.0, seed);
    d.head(nb) *= bones;
    d.tail(n - nb) *= soft;
    return d;
  };
  sim->updateState(increment(0.02, 0.002, 3));
  sim->postUpdate();
  sim->preUpdate();
  sim->updateState(increment(0.03, 0.003, 5));
  placeGroundAndSphere(*sim);
  return sim;
}

inline std::unique_ptr<Simulable> softTermScenario(SoftModel model) {
  return softTermScenario(smallSoftAvatar(model));
}

/// The simulable's whole gradient (dynamic and potential parts).
inline VecX totalGradient(const Simulable& sim) {
  VecX g = VecX::Zero(sim.numDofs());
  sim.getDynamicGradientVector(g);
  sim.getPotentialGradientVector(g);
  return g;
}

inline MatX softTermHessian(const Simulable& sim, const EnergyTerm& term, bool psd) {
  std::vector<Triplet> triplets;
  term.addHessian(sim.termContext(), triplets, 0, psd);
  return denseFromTriplets(triplets, sim.numDofs());
}

/// Coordinates checked by differences: every bone DoF, the 30 soft coordinates of largest
/// gradient (where a local term such as contact acts) and 60 random soft ones.
inline std::vector<int> softTermCoordinates(const Simulable& sim, const VecX& g) {
  const int n = sim.numDofs(), nb = sim.numBoneDofs();
  std::vector<int> idx(static_cast<size_t>(nb));
  std::iota(idx.begin(), idx.end(), 0);
  std::vector<int> soft(static_cast<size_t>(n - nb));
  std::iota(soft.begin(), soft.end(), nb);
  const size_t top = std::min<size_t>(30, soft.size());
  std::partial_sort(soft.begin(), soft.begin() + long(top), soft.end(),
                    [&](int a, int b) { return std::abs(g[a]) > std::abs(g[b]); });
  idx.insert(idx.end(), soft.begin(), soft.begin() + long(top));
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> pick(nb, n - 1);
  for (int k = 0; k < 60; ++k) idx.push_back(pick(rng));
  std::sort(idx.begin(), idx.end());
  idx.erase(std::unique(idx.begin(), idx.end()), idx.end());
  return idx;
}

/// The term's gradient and exact Hessian against central differences (on softTermCoordinates;
/// rotation gradients pulled back to the chart), its Hessian symmetric, its PSD form positive
/// semidefinite, and none of the calls changing the state. `soft_soft`: the term has soft–soft
/// Hessian blocks (all but gravity, linear in u); `bone_coupling`: it couples bones and soft
/// state (all but elasticity, which reads u alone).
inline void expectSoftTermDerivatives(Simulable& sim, const EnergyTerm& term, bool soft_soft,
                                      bool bone_coupling, double tol = 1e-5) {
  const int n = sim.numDofs(), nb = sim.numBoneDofs();
  const VecX q0 = sim.getState();
  const double E0 = term.evaluate(sim.termContext(), nullptr, 0);
  const VecX g = termGradient(sim, term);
  const MatX H = softTermHessian(sim, term, false);
  ASSERT_GT(g.tail(n - nb).norm(), 0.0) << term.name() << ": soft gradient";
  if (soft_soft) {
    ASSERT_GT(H.bottomRightCorner(n - nb, n - nb).norm(), 0.0) << term.name() << ": soft Hessian";
  }
  if (bone_coupling) {
    ASSERT_GT(g.head(nb).norm(), 0.0) << term.name() << ": bone gradient";
    ASSERT_GT(H.topRightCorner(nb, n - nb).norm(), 0.0) << term.name() << ": bone–soft blocks";
  }
  EXPECT_LT((H - H.transpose()).cwiseAbs().maxCoeff(), 1e-9 * (1.0 + H.cwiseAbs().maxCoeff()))
      << term.name();
  const std::vector<int> idx = softTermCoordinates(sim, g);
  const int m = int(idx.size());
  const auto expand = [&](const VecX& sub) {
    VecX d = VecX::Zero(n);
    for (int k = 0; k < m; ++k) d[idx[size_t(k)]] = sub[k];
    return d;
  };
  const auto energy = [&](const VecX& sub) {
    return atMovedState(sim, expand(sub), [&] {
      return VecX::Constant(1, term.evaluate(sim.termContext(), nullptr, 0));
    });
  };
  const auto gradient = [&](const VecX& sub) {
    const VecX d = expand(sub);
    return atMovedState(sim, d, [&] {
      VecX gd = termGradient(sim, term);
      for (int b = 0; b < nb / 6; ++b)
        gd.segment<3>(6 * b + 3) =
            leftJacobianSO3(d.segment<3>(6 * b + 3)).transpose() * gd.segment<3>(6 * b + 3);
      VecX out(m);
      for (int k = 0; k < m; ++k) out[k] = gd[idx[size_t(k)]];
      return out;
    });
  };
  const VecX zero = VecX::Zero(m);
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(energy, zero, g(idx).transpose(), tol))
      << term.name();
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, zero, H(idx, idx), tol)) << term.name();
  // The PSD form: symmetric positive semidefinite.
  const MatX P = softTermHessian(sim, term, true);
  ASSERT_GT(P.norm(), 0.0) << term.name();
  EXPECT_LT((P - P.transpose()).cwiseAbs().maxCoeff(), 1e-9 * (1.0 + P.cwiseAbs().maxCoeff()))
      << term.name();
  // λ_min(P) > −ε ⇔ P + εI has a Cholesky factor (a tenth of an eigensolve's cost at FEM sizes).
  const double shift = 1e-8 * (1.0 + P.norm());
  EXPECT_EQ(Eigen::LLT<MatX>(P + shift * MatX::Identity(n, n)).info(), Eigen::Success)
      << term.name();
  // Derivative calls leave the state (and so the energy) as they found it.
  EXPECT_EQ((sim.getState() - q0).norm(), 0.0) << term.name();
  EXPECT_EQ(term.evaluate(sim.termContext(), nullptr, 0), E0) << term.name();
}

}  // namespace flsh::test
