// Newton's coarse presolve (NewtonOptions::coarse_presolve, src/solve/coarse_presolve.cpp) on an
// analytic objective whose two coarse DoFs are strongly nonlinear and whose fine DoFs follow them
// through a quadratic coupling: the same minimum with fewer iterations on every DoF, the
// iteration limit, no presolve without a coarse form, and the options' validation.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/solve/newton.h"
#include "support/test_support.h"

namespace flsh {
namespace {

constexpr int kCoarse = 2, kFine = 40;

/// E(c, f) = Σ_i (exp(c_i) − t c_i) + ½ (f − A c)ᵀ K (f − A c) + ½ ε ‖f‖², convex, minimum far
/// from 0 in c (t = 60: c* ≈ 4). A is small (the fine DoFs follow c weakly, as the tissue held
/// in the bones' frames follows them). Coarse DoFs: c (the first two).
class Coupled : public Objective {
 public:
  explicit Coupled(bool coarse_form) : coarse_form_(coarse_form), x(VecX::Zero(kCoarse + kFine)) {
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
  void step(const VecX& dq) override { x += dq; }
  void push() override { stack_.push_back(x); }
  void pop() override {
    x = stack_.back();
    stack_.pop_back();
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
  VecX x;
  MatX A, K;
  int whole_hessians = 0;

 private:
  std::vector<VecX> stack_;
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
