// Newton with directions from Objective::approximateHessian (NewtonOptions::approximate_hessian):
// a stiffening convex objective whose approximation is its constant quadratic part converges to
// the exact minimum; a poor or indefinite approximation hands over to the exact directions; an
// objective without one is solved exactly as with the option off.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <random>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/solve/newton.h"
#include "solve/vector_state_objective.h"
#include "support/test_support.h"

namespace flsh {
namespace {

/// E(x) = ½ xᵀ A x − bᵀ x + c Σ x_i⁴ (convex, stiffening away from 0); the approximate Hessian
/// is `scale` · A (A: the exact Hessian at x = 0), when `has_approximation`.
class Stiffening : public test::VectorStateObjective {
 public:
  Stiffening(int n, double c, unsigned seed) : VectorStateObjective(VecX::Zero(n)), c_(c) {
    std::mt19937 rng(seed);
    std::normal_distribution<double> gauss(0.0, 1.0);
    MatX B(n, n);
    b_.resize(n);
    for (int i = 0; i < n; ++i) {
      b_[i] = 3.0 * gauss(rng);
      for (int j = 0; j < n; ++j) B(i, j) = gauss(rng);
    }
    A_ = B.transpose() * B / n + MatX::Identity(n, n);
  }

  int numDofs() const override { return int(x.size()); }
  double energy() override { return 0.5 * x.dot(A_ * x) - b_.dot(x) + c_ * x.array().pow(4).sum(); }
  void gradient(VecX& g) override { g = A_ * x - b_ + VecX(4.0 * c_ * x.array().pow(3)); }
  void hessian(SpMat& H, bool) override {
    ++exact_hessians;
    H = (A_ + MatX(VecX(12.0 * c_ * x.array().square()).asDiagonal())).sparseView();
  }
  bool approximateHessian(SpMat& H) override {
    if (!has_approximation) return false;
    ++approximations;
    H = (scale * A_).sparseView();
    return true;
  }

  bool has_approximation = true;
  double scale = 1.0;
  int exact_hessians = 0, approximations = 0;

 private:
  MatX A_;
  VecX b_;
  double c_;
};

NewtonOptions tight(bool approximate) {
  NewtonOptions o;
  o.gradient_tolerance = 1e-11;
  o.max_iterations = 200;
  o.approximate_hessian = approximate;
  return o;
}

// The reference: plain Newton on the exact Hessian.
VecX exactMinimum(double c) {
  Stiffening f(20, c, 7);
  f.has_approximation = false;
  const NewtonResult r = newtonSolve(f, tight(false));
  EXPECT_TRUE(r.converged) << r.message;
  return f.x;
}

TEST(NewtonApproximate, ConvergesToTheExactMinimumOnTheApproximation) {
  const double c = 1e-3;  // mild stiffening: the constant part is a good approximation
  const VecX expected = exactMinimum(c);
  for (bool reuse : {false, true}) {
    SCOPED_TRACE(reuse ? "reusing its factor" : "assembled every iteration");
    Stiffening f(20, c, 7);
    NewtonOptions o = tight(true);
    o.approximate_reuse = reuse;
    const NewtonResult r = newtonSolve(f, o);
    ASSERT_TRUE(r.converged) << r.message;
    EXPECT_LT((f.x - expected).lpNorm<Eigen::Infinity>(), 1e-9);
    EXPECT_GT(r.approximate_directions, 2);
    // Each direction either assembled the approximation or reused the last factor of it.
    EXPECT_EQ(r.approximate_directions - r.approximate_reuses, f.approximations);
    if (reuse)
      EXPECT_GT(r.approximate_reuses, 0);
    else
      EXPECT_EQ(r.approximate_reuses, 0);
    EXPECT_EQ(r.hessian_evaluations, f.exact_hessians);
    // While the approximation converges fast enough, no exact Hessian is assembled.
    EXPECT_LT(f.exact_hessians, r.iterations);
  }
}

// Solves the objective (stiffening c, approximation `scale` · A) with the approximation on and
// checks that it reaches the exact minimum; returns the result and the exact Hessians assembled.
struct HandOver {
  NewtonResult result;
  int exact_hessians = 0;
};
HandOver solveWithApproximation(double c, double scale, double step_tolerance = 1e-9) {
  const VecX expected = exactMinimum(c);
  Stiffening f(20, c, 7);
  f.scale = scale;
  NewtonOptions o = tight(true);
  o.step_tolerance = step_tolerance;
  HandOver h{newtonSolve(f, o), 0};
  h.exact_hessians = f.exact_hessians;
  EXPECT_TRUE(h.result.converged) << h.result.message;
  EXPECT_LE(h.result.gradient_norm, 10.0 * o.gradient_tolerance) << h.result.message;
  EXPECT_LT((f.x - expected).lpNorm<Eigen::Infinity>(), 1e-9);
  return h;
}

TEST(NewtonApproximate, APoorApproximationHandsOverToTheExactDirections) {
  // 50× too stiff: its full steps are accepted but shrink the gradient by ~2 % only.
  const HandOver h = solveWithApproximation(0.01, 50.0);
  EXPECT_EQ(h.result.approximate_directions, 1);  // one slow step, then the exact ones
  EXPECT_GT(h.exact_hessians, 0);
}

TEST(NewtonApproximate, ASmallApproximateStepDoesNotEndTheSolve) {
  // 1e8× too stiff: the first step is ~1e-8 of the distance, below step_tolerance, which ends a
  // solve of exact directions but not of the approximation's linear rate.
  const HandOver h = solveWithApproximation(0.01, 1e8, 1e-6);
  EXPECT_EQ(h.result.approximate_directions, 1);
}

TEST(NewtonApproximate, AnIndefiniteApproximationHandsOverToTheExactDirections) {
  const HandOver h = solveWithApproximation(0.01, -1.0);  // its factorization fails
  EXPECT_EQ(h.result.approximate_directions, 1);
  EXPECT_GT(h.exact_hessians, 0);
}

TEST(NewtonApproximate, StrongStiffeningStillConverges) {
  // The quartic dominates: the approximation's steps overshoot, the line search cuts them and
  // the exact directions take over.
  const HandOver h = solveWithApproximation(10.0, 1.0);
  EXPECT_GE(h.result.approximate_directions, 1);
  EXPECT_GT(h.exact_hessians, 0);
}

TEST(NewtonApproximate, WithoutAnApproximationTheOptionChangesNothing) {
  Stiffening on(20, 0.5, 9), off(20, 0.5, 9);
  on.has_approximation = off.has_approximation = false;
  const NewtonResult a = newtonSolve(on, tight(true));
  const NewtonResult b = newtonSolve(off, tight(false));
  ASSERT_TRUE(a.converged) << a.message;
  EXPECT_EQ(a.approximate_directions, 0);
  EXPECT_EQ(a.iterations, b.iterations);
  EXPECT_EQ(on.x, off.x);
}

TEST(NewtonApproximate, RefusesARatioOutsideZeroOne) {
  Stiffening f(4, 0.1, 3);
  for (double ratio : {0.0, 1.0, -0.5, std::nan("")}) {
    NewtonOptions o = tight(true);
    o.approximate_max_ratio = ratio;
    EXPECT_THROW(newtonSolve(f, o), InputError) << ratio;
  }
}

}  // namespace
}  // namespace flsh
