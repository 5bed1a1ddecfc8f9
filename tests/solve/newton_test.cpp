// Newton's method on analytic objectives: a convex quadratic (one step), Rosenbrock (line
// search), a rotation objective in the increment chart R ← exp([δ]×) R, indefinite Hessians
// (regularization) and energies that are infinite in part of the space (never NaN).
#include "flsh/solve/newton.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <functional>
#include <random>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/core/rotation.h"
#include "solve/vector_state_objective.h"
#include "support/test_support.h"

namespace flsh {
namespace {

/// An objective over x ∈ Rⁿ from callbacks; counts how deep its push/pop stack is. With
/// `can_discard` off it exercises Newton's pop-and-reapply fallback.
class FunctionObjective : public test::VectorStateObjective {
 public:
  using EnergyFn = std::function<double(const VecX&)>;
  using GradientFn = std::function<VecX(const VecX&)>;
  using HessianFn = std::function<MatX(const VecX&)>;

  FunctionObjective(VecX x0, EnergyFn e, GradientFn g, HessianFn h, bool can_discard = true)
      : VectorStateObjective(std::move(x0), can_discard), e_(e), g_(g), h_(h) {}

  int numDofs() const override { return int(x.size()); }
  double energy() override {
    ++energy_calls;
    return e_(x);
  }
  void gradient(VecX& g) override { g = g_(x); }
  void hessian(SpMat& H, bool) override { H = h_(x).sparseView(); }

  int energy_calls = 0;

 private:
  EnergyFn e_;
  GradientFn g_;
  HessianFn h_;
};

TEST(Newton, SolvesAConvexQuadraticInOneStep) {
  std::mt19937 rng(4);
  std::normal_distribution<double> gauss(0.0, 1.0);
  const int n = 12;
  MatX B(n, n);
  VecX b(n);
  for (int i = 0; i < n; ++i) {
    b[i] = gauss(rng);
    for (int j = 0; j < n; ++j) B(i, j) = gauss(rng);
  }
  const MatX A = B.transpose() * B + MatX::Identity(n, n);
  FunctionObjective f(
      VecX::Zero(n), [&](const VecX& x) { return 0.5 * x.dot(A * x) - b.dot(x); },
      [&](const VecX& x) { return VecX(A * x - b); }, [&](const VecX&) { return A; });
  const NewtonResult r = newtonSolve(f);
  EXPECT_TRUE(r.converged) << r.message;
  EXPECT_EQ(r.iterations, 1);
  EXPECT_EQ(r.line_search_steps, 0);
  EXPECT_EQ(r.regularizations, 0);
  const VecX expected = A.ldlt().solve(b);
  EXPECT_LT((f.x - expected).lpNorm<Eigen::Infinity>(), 1e-10);
  EXPECT_NEAR(r.energy, -0.5 * b.dot(expected), 1e-10);
  EXPECT_LE(r.gradient_norm, 1e-9);
  EXPECT_EQ(f.stackDepth(), 0u);
}

FunctionObjective rosenbrock(bool can_discard) {
  return FunctionObjective(
      (VecX(2) << -1.2, 1.0).finished(),
      [](const VecX& x) { return (1 - x[0]) * (1 - x[0]) + 100 * std::pow(x[1] - x[0] * x[0], 2); },
      [](const VecX& x) {
        VecX g(2);
        g << -2 * (1 - x[0]) - 400 * x[0] * (x[1] - x[0] * x[0]), 200 * (x[1] - x[0] * x[0]);
        return g;
      },
      [](const VecX& x) {
        MatX H(2, 2);
        H << 2 - 400 * (x[1] - 3 * x[0] * x[0]), -400 * x[0], -400 * x[0], 200;
        return H;
      },
      can_discard);
}

TEST(Newton, MinimizesRosenbrockWithTheLineSearch) {
  for (bool can_discard : {true, false}) {
    FunctionObjective f = rosenbrock(can_discard);
    NewtonOptions options;
    options.max_iterations = 100;
    options.gradient_tolerance = 1e-10;
    const NewtonResult r = newtonSolve(f, options);
    EXPECT_TRUE(r.converged) << r.message;
    EXPECT_GT(r.line_search_steps, 0);  // the full Newton step overshoots on the way
    EXPECT_GT(r.iterations, 5);
    EXPECT_LT((f.x - Eigen::Vector2d(1.0, 1.0)).norm(), 1e-6) << f.x.transpose();
    EXPECT_LT(r.energy, 1e-12);
    EXPECT_EQ(f.stackDepth(), 0u) << "can_discard " << can_discard;
  }
}

/// Rosenbrock that also evaluates its energy and gradient in one pass (Objective::
/// energyAndGradient) and counts the calls of each kind.
class FusedRosenbrock : public FunctionObjective {
 public:
  explicit FusedRosenbrock(bool can_discard) : FunctionObjective(rosenbrock(can_discard)) {}
  void gradient(VecX& g) override {
    ++gradient_calls;
    FunctionObjective::gradient(g);
  }
  bool energyAndGradient(double& energy, VecX& g) override {
    ++fused_calls;
    energy = FunctionObjective::energy();
    --energy_calls;  // counted as a fused call
    FunctionObjective::gradient(g);
    return true;
  }
  int gradient_calls = 0, fused_calls = 0;
};

// With energyAndGradient Newton takes the same steps (the accepted trial's gradient is the next
// iteration's; rejected trials, which Rosenbrock has, leave the current gradient alone) and
// never calls energy() or gradient() apart.
TEST(Newton, FusedEnergyAndGradientTakeTheSameSteps) {
  for (bool can_discard : {true, false}) {
    SCOPED_TRACE(can_discard ? "discard" : "pop and step again");
    NewtonOptions options;
    options.max_iterations = 100;
    options.gradient_tolerance = 1e-10;
    FunctionObjective plain = rosenbrock(can_discard);
    const NewtonResult a = newtonSolve(plain, options);
    FusedRosenbrock fused(can_discard);
    const NewtonResult b = newtonSolve(fused, options);
    ASSERT_TRUE(a.converged) << a.message;
    ASSERT_GT(a.line_search_steps, 0);
    EXPECT_TRUE(b.converged) << b.message;
    EXPECT_EQ(b.iterations, a.iterations);
    EXPECT_EQ(b.line_search_steps, a.line_search_steps);
    EXPECT_EQ(fused.x, plain.x);
    EXPECT_EQ(b.energy, a.energy);
    EXPECT_EQ(fused.energy_calls, 0);
    EXPECT_EQ(fused.gradient_calls, 0);
    // One pass at the start and one per trial state (accepted or not).
    EXPECT_EQ(fused.fused_calls, 1 + b.iterations + b.line_search_steps);
    EXPECT_EQ(plain.energy_calls, fused.fused_calls);
    EXPECT_EQ(fused.stackDepth(), 0u);
  }
}

/// ‖R − R*‖²_F over SO(3) with R ← exp([δ]×) R. With M = R R*ᵀ:
/// E(δ) = const − 2 tr(R*ᵀ exp([δ]×) R), gradient −2 vee(M − Mᵀ), Hessian 2 tr(M) I − (M + Mᵀ).
class RotationObjective : public Objective {
 public:
  RotationObjective(const Mat3& R0, const Mat3& target) : R(R0), target_(target) {}
  int numDofs() const override { return 3; }
  double energy() override { return (R - target_).squaredNorm(); }
  void gradient(VecX& g) override {
    const Mat3 M = R * target_.transpose();
    g = -2.0 * Vec3(M(1, 2) - M(2, 1), M(2, 0) - M(0, 2), M(0, 1) - M(1, 0));
  }
  void hessian(SpMat& H, bool) override {
    const Mat3 M = R * target_.transpose();
    const Mat3 dense = 2.0 * M.trace() * Mat3::Identity() - (M + M.transpose());
    H = MatX(dense).sparseView();
  }
  void step(const VecX& dq) override { R = rodrigues(Vec3(dq)) * R; }
  void push() override { stack_.push_back(R); }
  void pop() override {
    R = stack_.back();
    stack_.pop_back();
  }
  bool discardPushed() override {
    stack_.pop_back();
    return true;
  }
  Mat3 R;

 private:
  Mat3 target_;
  std::vector<Mat3> stack_;
};

TEST(Newton, RotationObjectiveDerivativesMatchFiniteDifferences) {
  const Mat3 R0 = rodrigues(Vec3(0.4, -0.2, 0.9)), target = rodrigues(Vec3(-0.3, 0.5, 0.1));
  RotationObjective f(R0, target);
  // Energy and gradient of δ ↦ E(exp([δ]×) R0), at δ = 0.
  const auto energy_at = [&](const VecX& d) {
    RotationObjective probe(rodrigues(Vec3(d)) * R0, target);
    return VecX::Constant(1, probe.energy());
  };
  VecX g;
  f.gradient(g);
  EXPECT_TRUE(test::jacobianMatchesFiniteDifferences(energy_at, VecX::Zero(3), g.transpose()));
  // Hessian of δ ↦ E(exp([δ]×) R0): the gradient of the pulled-back function is J_l(δ)ᵀ times
  // the chart gradient at exp([δ]×) R0.
  const auto pulled_back_gradient = [&](const VecX& d) {
    RotationObjective probe(rodrigues(Vec3(d)) * R0, target);
    VecX gd;
    probe.gradient(gd);
    return VecX(leftJacobianSO3(Vec3(d)).transpose() * gd);
  };
  SpMat H;
  f.hessian(H, false);
  EXPECT_TRUE(
      test::jacobianMatchesFiniteDifferences(pulled_back_gradient, VecX::Zero(3), MatX(H), 1e-6));
}

TEST(Newton, MinimizesARotationObjectiveInTheIncrementChart) {
  const Mat3 target = rodrigues(Vec3(0.2, -1.0, 0.4));
  // Near the target (H positive definite) and 2.6 rad away (tr M < 0: H indefinite at first).
  for (const Vec3& start : {Vec3(0.3, -0.8, 0.5), Vec3(2.2, 1.0, -0.9)}) {
    RotationObjective f(rodrigues(start), target);
    NewtonOptions options;
    options.max_iterations = 50;
    options.gradient_tolerance = 1e-12;
    const NewtonResult r = newtonSolve(f, options);
    EXPECT_TRUE(r.converged) << r.message;
    EXPECT_LT((f.R - target).norm(), 1e-8) << "start " << start.transpose();
    EXPECT_LT((f.R.transpose() * f.R - Mat3::Identity()).norm(), 1e-12);
  }
}

TEST(Newton, RegularizesAnIndefiniteHessian) {
  // E = x⁴/4 − x²/2 + y²: H = diag(3x² − 1, 2) is indefinite at x = 0.1; minima at x = ±1.
  FunctionObjective f(
      (VecX(2) << 0.1, 0.5).finished(),
      [](const VecX& x) { return std::pow(x[0], 4) / 4 - x[0] * x[0] / 2 + x[1] * x[1]; },
      [](const VecX& x) {
        return VecX((VecX(2) << std::pow(x[0], 3) - x[0], 2 * x[1]).finished());
      },
      [](const VecX& x) { return MatX((MatX(2, 2) << 3 * x[0] * x[0] - 1, 0, 0, 2).finished()); });
  NewtonOptions options;
  options.max_iterations = 100;
  const NewtonResult r = newtonSolve(f, options);
  EXPECT_TRUE(r.converged) << r.message;
  EXPECT_GT(r.regularizations, 0);
  EXPECT_NEAR(f.x[0], 1.0, 1e-6);
  EXPECT_NEAR(f.x[1], 0.0, 1e-6);
}

// E = x − log x (minimum at x = 1) is NaN for x < 0 and +∞ at 0; the full Newton step from
// x = 5 lands at x = −15.
FunctionObjective logBarrier(double x0) {
  return FunctionObjective(
      VecX::Constant(1, x0), [](const VecX& x) { return x[0] - std::log(x[0]); },
      [](const VecX& x) { return VecX::Constant(1, 1.0 - 1.0 / x[0]); },
      [](const VecX& x) { return MatX::Constant(1, 1, 1.0 / (x[0] * x[0])); });
}

TEST(Newton, NeverStepsIntoInfiniteOrNanEnergy) {
  FunctionObjective f = logBarrier(5.0);
  NewtonOptions options;
  options.gradient_tolerance = 1e-12;
  const NewtonResult r = newtonSolve(f, options);
  EXPECT_TRUE(r.converged) << r.message;
  EXPECT_GT(r.line_search_steps, 0);
  EXPECT_NEAR(f.x[0], 1.0, 1e-8);
  EXPECT_TRUE(std::isfinite(r.energy));
}

TEST(Newton, StopsWithAMessageWhenNoStepDecreases) {
  // Without halvings, the only trial (x = −15) has a NaN energy: the state stays at x = 5.
  FunctionObjective f = logBarrier(5.0);
  NewtonOptions options;
  options.max_line_search_steps = 0;
  const NewtonResult r = newtonSolve(f, options);
  EXPECT_FALSE(r.converged);
  EXPECT_NE(r.message.find("line search"), std::string::npos) << r.message;
  EXPECT_EQ(f.x[0], 5.0);
  EXPECT_EQ(f.stackDepth(), 0u);
  EXPECT_TRUE(std::isfinite(r.energy));
  // An initial state with infinite energy: nothing is tried, the state is kept.
  FunctionObjective g = logBarrier(0.0);
  const NewtonResult r0 = newtonSolve(g);
  EXPECT_FALSE(r0.converged);
  EXPECT_EQ(g.x[0], 0.0);
  EXPECT_NE(r0.message.find("not finite"), std::string::npos) << r0.message;
}

TEST(Newton, ReportsMaxIterationsAndValidatesOptions) {
  FunctionObjective f = rosenbrock(true);
  NewtonOptions options;
  options.max_iterations = 2;
  const NewtonResult r = newtonSolve(f, options);
  EXPECT_FALSE(r.converged);
  EXPECT_TRUE(r.max_iterations_reached);
  EXPECT_EQ(r.iterations, 2);
  EXPECT_NE(r.message.find("max_iterations"), std::string::npos) << r.message;
  options.max_iterations = 100;  // converged, or failed otherwise: not at the limit
  FunctionObjective again = rosenbrock(true);
  const NewtonResult done = newtonSolve(again, options);
  EXPECT_TRUE(done.converged);
  EXPECT_FALSE(done.max_iterations_reached);

  NewtonOptions bad;
  bad.armijo = 1.5;
  const std::string message = test::messageOf<InputError>([&] { newtonSolve(f, bad); });
  EXPECT_NE(message.find("armijo"), std::string::npos) << message;
  EXPECT_NE(message.find("1.5"), std::string::npos) << message;
}

TEST(Newton, ReusesTheSolversAnalysisAcrossSolves) {
  // A sparse (tridiagonal) quartic-plus-quadratic in 50 unknowns, solved twice with one
  // CHOLMOD solver: the pattern never changes, so one analysis serves every factorization.
  const int n = 50;
  SpMat L(n, n);
  std::vector<Triplet> t;
  for (int i = 0; i < n; ++i) {
    t.emplace_back(i, i, 2.0);
    if (i > 0) t.emplace_back(i, i - 1, -1.0), t.emplace_back(i - 1, i, -1.0);
  }
  L.setFromTriplets(t.begin(), t.end());
  const VecX b = VecX::LinSpaced(n, -1.0, 1.0);
  FunctionObjective f(
      VecX::Zero(n),
      [&](const VecX& x) { return 0.5 * x.dot(L * x) + 0.25 * x.array().pow(4).sum() - b.dot(x); },
      [&](const VecX& x) { return VecX(L * x + VecX(x.array().pow(3)) - b); },
      [&](const VecX& x) {
        return MatX(MatX(L) + MatX(VecX(3 * x.array().square()).asDiagonal()));
      });
  auto solver = makeLinearSolver(LinearSolverType::Cholmod, n);
  const NewtonResult r1 = newtonSolve(f, {}, solver.get());
  ASSERT_TRUE(r1.converged) << r1.message;
  f.x.setConstant(0.3);
  const NewtonResult r2 = newtonSolve(f, {}, solver.get());
  ASSERT_TRUE(r2.converged) << r2.message;
  EXPECT_EQ(solver->numFactorizations(), r1.iterations + r2.iterations);
  EXPECT_EQ(solver->numAnalyses(), 1);
}

TEST(Newton, AddCountsSumsCountersAndTimingsOnly) {
  NewtonResult total;
  total.converged = true;
  total.energy = 7.0;
  total.message = "first";
  NewtonResult r;
  r.converged = false;
  r.energy = -1.0;
  r.gradient_norm = 3.0;
  r.message = "second";
  r.iterations = 1;
  r.line_search_steps = 2;
  r.regularizations = 3;
  r.psd_fallbacks = 4;
  r.hessian_evaluations = 5;
  r.approximate_directions = 9;
  r.approximate_reuses = 11;
  r.factorizations = 6;
  r.cg_iterations = 7;
  r.seconds_energy = 0.5;
  r.seconds_gradient = 0.25;
  r.seconds_hessian = 0.125;
  r.seconds_factorization = 1.5;
  r.seconds_solve = 2.5;
  total.addCounts(r);
  total.addCounts(r);
  EXPECT_EQ(total.iterations, 2);
  EXPECT_EQ(total.line_search_steps, 4);
  EXPECT_EQ(total.regularizations, 6);
  EXPECT_EQ(total.psd_fallbacks, 8);
  EXPECT_EQ(total.hessian_evaluations, 10);
  EXPECT_EQ(total.approximate_directions, 18);
  EXPECT_EQ(total.approximate_reuses, 22);
  EXPECT_EQ(total.factorizations, 12);
  EXPECT_EQ(total.cg_iterations, 14);
  EXPECT_EQ(total.seconds_energy, 1.0);
  EXPECT_EQ(total.seconds_gradient, 0.5);
  EXPECT_EQ(total.seconds_hessian, 0.25);
  EXPECT_EQ(total.seconds_factorization, 3.0);
  EXPECT_EQ(total.seconds_solve, 5.0);
  // The outcome of a solve is not a count: left as it was.
  EXPECT_TRUE(total.converged);
  EXPECT_EQ(total.energy, 7.0);
  EXPECT_EQ(total.gradient_norm, 0.0);
  EXPECT_EQ(total.message, "first");
}

}  // namespace
}  // namespace flsh
