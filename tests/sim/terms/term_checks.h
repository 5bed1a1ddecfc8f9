// Finite-difference checks shared by the energy terms' tests (tests/sim/terms/*_test.cpp): each
// term's value, gradient, exact Hessian and parameter products at a simulable's state, the term
// alone (EnergyTerm, energy_term.h). Every check first asserts the analytic quantity is nonzero.
#pragma once

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <memory>
#include <string>

#include "flsh/sim/simulable.h"
#include "support/test_support.h"

namespace flsh::test {

/// The term of `sim` named `name` (Simulable::energyTerms).
inline const EnergyTerm& termNamed(const Simulable& sim, const std::string& name) {
  for (const EnergyTerm* term : sim.energyTerms())
    if (name == term->name()) return *term;
  throw std::runtime_error("no energy term named " + name);
}

/// A ground plane 1.5 cm above the simulable's lowest node and a sphere pressing into its
/// frontmost node (a curved collider).
inline void placeGroundAndSphere(Simulable& sim) {
  const MatX3 nodes = sim.getNodes();
  Eigen::Index lowest, front;
  nodes.col(1).minCoeff(&lowest);
  nodes.col(2).maxCoeff(&front);
  const Vec3 tip = nodes.row(front).transpose();
  sim.setColliders({Collider::plane(Vec3(0, nodes(lowest, 1) + 0.015, 0), Vec3::UnitY()),
                    Collider::sphere(tip + Vec3(0, 0, 0.04), 0.05)});
}

/// A walking avatar one step in with a velocity history, moved off its prediction, a ground
/// plane 1.5 cm above its lowest vertex and a sphere pressing into its frontmost vertex (a
/// curved collider), tracking its mocap: every term is active (600-vertex synthetic body).
inline std::unique_ptr<Simulable> termScenario() {
  const SmallScene& scene = smallScene(600, 1.0);
  auto sim = std::make_unique<Simulable>(scene.avatar, scene.walk);
  sim->initialize();
  sim->preUpdate();
  const int n = sim->numDofs();
  const VecX predicted = sim->getState();
  const VecX N = predicted + randomVector(n, 0.02, 3);
  sim->setState(N + randomVector(n, 0.02, 4));
  sim->postUpdate();
  sim->setState(N);
  sim->postUpdate();
  sim->setState(predicted + randomVector(n, 0.03, 5));
  placeGroundAndSphere(*sim);
  return sim;
}

inline double termEnergy(const Simulable& sim, const EnergyTerm& term) {
  return term.evaluate(sim.termContext(), nullptr, 0);
}

inline VecX termGradient(const Simulable& sim, const EnergyTerm& term) {
  VecX g = VecX::Zero(sim.numDofs());
  term.evaluate(sim.termContext(), &g, 0);
  return g;
}

/// The term's gradient against central differences of its energy along the increment chart,
/// and its exact Hessian against central differences of the pulled-back gradient.
inline void expectTermDerivatives(Simulable& sim, const EnergyTerm& term, double tol) {
  const VecX q0 = sim.getState();
  const int n = sim.numDofs();
  const VecX g = termGradient(sim, term);
  ASSERT_GT(g.norm(), 0.0) << term.name();
  std::vector<Triplet> triplets;
  term.addHessian(sim.termContext(), triplets, 0, false);
  const MatX H = denseFromTriplets(triplets, n);
  ASSERT_GT(H.norm(), 0.0) << term.name();
  const auto moved = [&](const VecX& d) {
    sim.setState(q0);
    sim.updateState(d);
  };
  const auto energy = [&](const VecX& d) {
    moved(d);
    VecX e(1);
    e[0] = termEnergy(sim, term);
    return e;
  };
  const auto gradient = [&](const VecX& d) {
    moved(d);
    return pullBackRotationGradient(termGradient(sim, term), d);
  };
  const VecX zero = VecX::Zero(n);
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(energy, zero, g.transpose(), tol)) << term.name();
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, zero, H, tol)) << term.name();
  sim.setState(q0);
  // The PSD form is symmetric positive semidefinite.
  triplets.clear();
  term.addHessian(sim.termContext(), triplets, 0, true);
  const MatX P = denseFromTriplets(triplets, n);
  EXPECT_LT((P - P.transpose()).norm(), 1e-9 * (1.0 + P.norm())) << term.name();
  EXPECT_GT(Eigen::SelfAdjointEigenSolver<MatX>(P).eigenvalues().minCoeff(),
            -1e-8 * (1.0 + P.norm()))
      << term.name();
}

/// The term's parameter Jacobian ∂g/∂p against central differences of its gradient under
/// setParameter; then its vector–Jacobian product (λ random) and Jacobian–vector product (ṗ
/// random) against the Jacobian: the three forms of the one derivative.
inline void expectTermParameterProducts(Simulable& sim, const EnergyTerm& term, SimParameter p,
                                        double tol, bool relative_scale = false) {
  const int n = sim.numDofs();
  const VecX p0 = sim.getParameter(p);
  const int size = int(p0.size());
  const VecX scale = relative_scale ? VecX(p0.cwiseAbs()) : VecX::Ones(size);
  ParameterProducts<MatX> jac;
  jac[p] = MatX::Zero(n, size);
  term.addParameterJacobians(sim.termContext(), jac);
  const MatX analytic = jac[p] * scale.asDiagonal();  // n × size
  ASSERT_GT(analytic.norm(), 0.0) << term.name() << ", " << simParameterInfo(p).name;
  const auto gradient = [&](const VecX& delta) {
    sim.setParameter(p, p0 + scale.cwiseProduct(delta));
    return termGradient(sim, term);
  };
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(gradient, VecX::Zero(size), analytic, tol))
      << term.name() << ", " << simParameterInfo(p).name;
  sim.setParameter(p, p0);
  const VecX lambda = randomVector(n, 1.0, 11);
  ParameterProducts<VecX> vjp;
  vjp[p] = VecX::Zero(size);
  term.addParameterProducts(sim.termContext(), lambda, vjp);
  const VecX expected_vjp = jac[p].transpose() * lambda;
  EXPECT_LT((vjp[p] - expected_vjp).norm(), 1e-10 * (1.0 + expected_vjp.norm()))
      << term.name() << ", " << simParameterInfo(p).name;
  const VecX direction = randomVector(size, 1.0, 13);
  ParameterDirection along{};
  along[size_t(p)] = &direction;
  std::vector<VecX> jvp(1, VecX::Zero(n));
  term.addParameterTangents(sim.termContext(), {along}, jvp);
  const VecX expected_jvp = jac[p] * direction;
  EXPECT_LT((jvp[0] - expected_jvp).norm(), 1e-10 * (1.0 + expected_jvp.norm()))
      << term.name() << ", " << simParameterInfo(p).name;
}

/// A group the term does not depend on is left untouched (zero products of each form).
inline void expectNoParameterProducts(const Simulable& sim, const EnergyTerm& term,
                                      SimParameter p) {
  const int n = sim.numDofs(), size = sim.parameterSize(p);
  ParameterProducts<VecX> out;
  out[p] = VecX::Zero(size);
  term.addParameterProducts(sim.termContext(), randomVector(n, 1.0, 12), out);
  EXPECT_EQ(out[p].norm(), 0.0) << term.name() << ", " << simParameterInfo(p).name;
  ParameterProducts<MatX> jac;
  jac[p] = MatX::Zero(n, size);
  term.addParameterJacobians(sim.termContext(), jac);
  EXPECT_EQ(jac[p].norm(), 0.0) << term.name() << ", " << simParameterInfo(p).name;
  const VecX direction = randomVector(size, 1.0, 14);
  ParameterDirection along{};
  along[size_t(p)] = &direction;
  std::vector<VecX> jvp(1, VecX::Zero(n));
  term.addParameterTangents(sim.termContext(), {along}, jvp);
  EXPECT_EQ(jvp[0].norm(), 0.0) << term.name() << ", " << simParameterInfo(p).name;
}

}  // namespace flsh::test
