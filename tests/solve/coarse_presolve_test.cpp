// Newton's coarse presolve (NewtonOptions::coarse_presolve, src/solve/coarse_presolve.cpp) on an
// analytic objective whose two coarse DoFs are strongly nonlinear and whose fine DoFs follow them
// through a quadratic coupling: the same minimum with fewer iterations on every DoF, the
// iteration limit, no presolve without a coarse form, and the options' validation.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <memory>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/solve/newton.h"
#include "solve/vector_state_objective.h"
#include "support/test_support.h"

namespace flsh {
namespace {

constexpr int kCoarse = 2, kFine = 40;

/// E(c, f) = Σ_i (exp(c_i) − t c_i) + ½ (f − A c)ᵀ K (f − A c) + ½ ε ‖f‖², convex, minimum far
/// from 0 in c (t = 60: c* ≈ 4). A is small (the fine DoFs follow c weakly, as the tissue held
/// in the bones' frames follows them). Coarse DoFs: c (the first two).
class Coupled : public test::VectorStateObjective {
 public:
  explicit Coupled(bool coarse_form)
      : VectorStateObjective(VecX::Zero(kCoarse + kFine)), coarse_form_(coarse_form) {
    A = MatX::Zero(kFine, kCoarse);
    for (int i = 0; i < kFine; ++i) A(i, i % kCoarse) = 0.05 + 0.001 * i;
    K = MatX::Identity(kFine, kFine) * 3.0;
    for (int i = 0; i + 1 < kFine; ++i) K(i, i + 1) = K(i + 1, i) = -1.0;
  }
  int numDofs() const override { return kCoarse + kFine; }
  double energy() override {
    const VecX c = x.head(kCoarse), f = x.tail(kFine), r = f - A * c;
    double E = 0.5 * r.dot(K * r) + 0.5 * kEps * f.squaredNorm();
    for (int i = 0; i < kCoarse; ++i) E += std::exp(c[i]) - kTarget * c[i];
    return E;
  }
  void gradient(VecX& g) override {
    const VecX c = x.head(kCoarse), f = x.tail(kFine), Kr = K * (f - A * c);
    g.resize(numDofs());
    g.head(kCoarse) = -A.transpose() * Kr;
    for (int i = 0; i < kCoarse; ++i) g[i] += std::exp(c[i]) - kTarget;
    g.tail(kFine) = Kr + kEps * f;
  }
  MatX dense() const {
    MatX H = MatX::Zero(numDofs(), numDofs());
    H.topLeftCorner(kCoarse, kCoarse) = A.transpose() * K * A;
    for (int i = 0; i < kCoarse; ++i) H(i, i) += std::exp(x[i]);
    H.topRightCorner(kCoarse, kFine) = -A.transpose() * K;
    H.bottomLeftCorner(kFine, kCoarse) = -K * A;
    H.bottomRightCorner(kFine, kFine) = K + kEps * MatX::Identity(kFine, kFine);
    return H;
  }
  void hessian(SpMat& H, bool) override {
    ++whole_hessians;
    H = dense().sparseView();
  }
  void coarseDofs(std::vector<int>& dofs) const override { dofs = {0, 1}; }
  bool coarseEnergyAndGradient(double& E, VecX& g) override {
    if (!coarse_form_) return false;
    E = energy();
    VecX whole;
    gradient(whole);
    g = whole.head(kCoarse);
    return true;
  }
  void coarseHessian(MatX& H, bool) override { H = dense().topLeftCorner(kCoarse, kCoarse); }

  static constexpr double kTarget = 60.0, kEps = 0.1;
  bool coarse_form_;
  MatX A, K;
  int whole_hessians = 0;
};

NewtonOptions optionsWith(int presolve) {
  NewtonOptions o;
  o.gradient_tolerance = 1e-12;
  o.coarse_presolve.max_iterations = presolve;
  return o;
}

TEST(CoarsePresolve, SameMinimumWithFewerWholeIterations) {
  Coupled plain(true), presolved(true);
  const NewtonResult a = newtonSolve(plain, optionsWith(0));
  const NewtonResult b = newtonSolve(presolved, optionsWith(20));
  ASSERT_TRUE(a.converged) << a.message;
  ASSERT_TRUE(b.converged) << b.message;
  EXPECT_EQ(a.coarse_iterations, 0);
  EXPECT_GT(b.coarse_iterations, 0);
  EXPECT_LT(b.iterations, a.iterations);
  EXPECT_LT(presolved.whole_hessians, plain.whole_hessians);
  ASSERT_GT(plain.x.head(kCoarse).cwiseAbs().minCoeff(), 1.0);  // far from the start
  EXPECT_LE((plain.x - presolved.x).cwiseAbs().maxCoeff(), 1e-9);
  // The tolerance stays relative to the start: the presolve does not make the solve tighter
  // than the gradient there asks (‖g‖∞ at the end within the same target).
  VecX g0;
  Coupled start(true);
  start.gradient(g0);
  EXPECT_LE(b.gradient_norm, 1e-12 * g0.lpNorm<Eigen::Infinity>());
}

TEST(CoarsePresolve, StopsAtItsIterationLimitAndLowersTheEnergy) {
  Coupled objective(true);
  const double start = objective.energy();
  NewtonOptions o = optionsWith(1);
  o.max_iterations = 0;  // the presolve alone
  const NewtonResult r = newtonSolve(objective, o);
  EXPECT_EQ(r.coarse_iterations, 1);
  EXPECT_EQ(r.iterations, 0);
  EXPECT_EQ(objective.whole_hessians, 0);
  EXPECT_LT(objective.energy(), start);
  EXPECT_TRUE(objective.x.tail(kFine).isZero(0.0)) << "the fine DoFs are held";
}

TEST(CoarsePresolve, NothingWithoutACoarseForm) {
  Coupled without(false), reference(true);
  const NewtonResult a = newtonSolve(without, optionsWith(20));
  const NewtonResult b = newtonSolve(reference, optionsWith(0));
  EXPECT_EQ(a.coarse_iterations, 0);
  EXPECT_EQ(a.iterations, b.iterations);
  EXPECT_EQ(without.x, reference.x);
}

/// Two bones' worth of coarse DoFs (two 6 × 6 blocks), each DoF exp(c_i) − t_i c_i, held fine
/// DoFs, and a spring ½ s (c_0 − c_6)² that couples the blocks when s > 0: the presolve hands
/// the coarse block to a sparse Cholesky in the pattern of its nonzero 6 × 6 blocks.
class TwoBones : public test::VectorStateObjective {
 public:
  static constexpr int kBones = 12, kHeld = 3;
  TwoBones() : VectorStateObjective(VecX::Zero(kBones + kHeld)) {}
  int numDofs() const override { return kBones + kHeld; }
  double target(int i) const { return 20.0 + 5.0 * i; }
  double energy() override {
    double E = 0.5 * spring * std::pow(x[0] - x[6], 2) + 0.5 * x.tail(kHeld).squaredNorm();
    for (int i = 0; i < kBones; ++i) E += std::exp(x[i]) - target(i) * x[i];
    return E;
  }
  void gradient(VecX& g) override {
    g = VecX::Zero(numDofs());
    for (int i = 0; i < kBones; ++i) g[i] = std::exp(x[i]) - target(i);
    g[0] += spring * (x[0] - x[6]);
    g[6] -= spring * (x[0] - x[6]);
    g.tail(kHeld) = x.tail(kHeld);
  }
  MatX dense() const {
    MatX H = MatX::Identity(numDofs(), numDofs());
    for (int i = 0; i < kBones; ++i) H(i, i) = std::exp(x[i]);
    H(0, 0) += spring;
    H(6, 6) += spring;
    H(0, 6) = H(6, 0) = -spring;
    return H;
  }
  void hessian(SpMat& H, bool) override { H = dense().sparseView(); }
  void coarseDofs(std::vector<int>& dofs) const override {
    dofs.resize(kBones);
    for (int i = 0; i < kBones; ++i) dofs[size_t(i)] = i;
  }
  bool coarseEnergyAndGradient(double& E, VecX& g) override {
    E = energy();
    VecX whole;
    gradient(whole);
    g = whole.head(kBones);
    return true;
  }
  void coarseHessian(MatX& H, bool) override { H = dense().topLeftCorner(kBones, kBones); }
  LinearSolver* coarseSolver() override { return kept.get(); }

  double spring = 0.0;
  std::unique_ptr<LinearSolver> kept = makeLinearSolver(LinearSolverType::SparseLLT, 0);
};

// The presolve alone to a tight tolerance from x = 0: the coarse gradient ends at ~0.
double presolvedCoarseGradient(TwoBones& objective) {
  objective.x.setZero();
  objective.x.tail(TwoBones::kHeld).setConstant(0.5);  // held: the presolve must not move them
  NewtonOptions o;
  o.max_iterations = 0;
  o.coarse_presolve.max_iterations = 60;
  o.coarse_presolve.relative_tolerance = 1e-12;
  const NewtonResult r = newtonSolve(objective, o);
  EXPECT_GT(r.coarse_iterations, 2);
  EXPECT_TRUE(objective.x.tail(TwoBones::kHeld).isConstant(0.5, 0.0));
  VecX g;
  objective.gradient(g);
  return g.head(TwoBones::kBones).lpNorm<Eigen::Infinity>();
}

TEST(CoarsePresolve, KeepsTheObjectivesSolverAndItsAnalysisWhileThePatternStays) {
  TwoBones objective;
  EXPECT_LT(presolvedCoarseGradient(objective), 1e-9);
  const int factorizations = objective.kept->numFactorizations();
  ASSERT_GT(factorizations, 2) << "the presolve factors with the objective's solver";
  EXPECT_EQ(objective.kept->numAnalyses(), 1);
  EXPECT_LT(presolvedCoarseGradient(objective), 1e-9);
  EXPECT_GT(objective.kept->numFactorizations(), factorizations);
  EXPECT_EQ(objective.kept->numAnalyses(), 1) << "same block pattern: the analysis is kept";

  // The spring couples the blocks: a new pattern, analysed again, and the coupled minimum.
  objective.spring = 40.0;
  EXPECT_LT(presolvedCoarseGradient(objective), 1e-9);
  EXPECT_EQ(objective.kept->numAnalyses(), 2);
  EXPECT_GT(std::abs(objective.x[0] - std::log(objective.target(0))), 0.05)
      << "the coupling moved the minimum";
}

TEST(CoarsePresolve, OptionsAreValidated) {
  for (const auto& [iterations, tolerance, key] :
       {std::tuple{-1, 1e-3, "coarse_presolve.max_iterations"},
        std::tuple{4, 0.0, "coarse_presolve.relative_tolerance"},
        std::tuple{4, 1.0, "coarse_presolve.relative_tolerance"}}) {
    Coupled objective(true);
    NewtonOptions o;
    o.coarse_presolve.max_iterations = iterations;
    o.coarse_presolve.relative_tolerance = tolerance;
    const std::string message = test::messageOf<InputError>([&] { newtonSolve(objective, o); });
    EXPECT_NE(message.find(key), std::string::npos) << message;
  }
}

}  // namespace
}  // namespace flsh
