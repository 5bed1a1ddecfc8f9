// Linear solvers: dense Cholesky and CHOLMOD agree with Eigen's dense LDLT on random sparse SPD
// systems, report non-positive-definite matrices, and keep the symbolic analysis while the
// pattern does not change.
#include "flsh/solve/linear_solver.h"

#include <gtest/gtest.h>
#include <omp.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <random>

#include "flsh/core/error.h"
#include "support/test_support.h"

namespace flsh {
namespace {

/// Random sparse SPD matrix BᵀB + shift·I (full storage), about `per_column` entries per column
/// of B.
SpMat randomSpd(int n, int per_column, unsigned seed, double shift = 0.1) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> row(0, n - 1);
  std::uniform_real_distribution<double> value(-1.0, 1.0);
  std::vector<Triplet> entries;
  for (int c = 0; c < n; ++c) {
    entries.emplace_back(c, c, 1.0 + value(rng));
    for (int k = 0; k < per_column; ++k) entries.emplace_back(row(rng), c, value(rng));
  }
  SpMat B(n, n);
  B.setFromTriplets(entries.begin(), entries.end());
  SpMat I(n, n);
  I.setIdentity();
  SpMat A = SpMat(B.transpose()) * B + shift * I;
  A.makeCompressed();
  return A;
}

VecX randomVector(int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  VecX b(n);
  for (int i = 0; i < n; ++i) b[i] = g(rng);
  return b;
}

double relativeError(const VecX& x, const VecX& reference) {
  return (x - reference).norm() / reference.norm();
}

class LinearSolverTest : public ::testing::TestWithParam<LinearSolverType> {};

TEST_P(LinearSolverTest, AgreesWithEigenDenseSolveOnRandomSpdMatrices) {
  for (int n : {1, 7, 60, 250}) {
    const SpMat A = randomSpd(n, 3, 11 + n);
    const VecX b = randomVector(n, 5 + n);
    const VecX reference = MatX(A).ldlt().solve(b);
    auto solver = makeLinearSolver(GetParam(), n);
    ASSERT_TRUE(solver->factorize(A)) << "n = " << n;
    EXPECT_LT(relativeError(solver->solve(b), reference), 1e-10) << "n = " << n;
    // A second right-hand side with the same factor.
    const VecX b2 = randomVector(n, 99 + n);
    EXPECT_LT(relativeError(solver->solve(b2), VecX(MatX(A).ldlt().solve(b2))), 1e-10);
  }
}

TEST_P(LinearSolverTest, ReadsOnlyTheLowerTriangle) {
  const int n = 40;
  const SpMat A = randomSpd(n, 3, 3);
  SpMat lower_only = A.triangularView<Eigen::Lower>();
  SpMat garbage_upper = lower_only;
  for (int k = 0; k < A.outerSize(); ++k)
    for (SpMat::InnerIterator it(A, k); it; ++it)
      if (it.row() < it.col()) garbage_upper.coeffRef(it.row(), it.col()) = 1e3;
  const VecX b = randomVector(n, 4);
  const VecX reference = MatX(A).ldlt().solve(b);
  auto solver = makeLinearSolver(GetParam(), n);
  ASSERT_TRUE(solver->factorize(garbage_upper));  // also not compressed
  EXPECT_LT(relativeError(solver->solve(b), reference), 1e-10);
}

TEST_P(LinearSolverTest, ReportsMatricesThatAreNotPositiveDefinite) {
  const int n = 30;
  auto solver = makeLinearSolver(GetParam(), n);
  // Indefinite: an SPD matrix shifted by more than its smallest eigenvalue.
  const SpMat spd = randomSpd(n, 3, 21, 0.0);
  const double lowest = Eigen::SelfAdjointEigenSolver<MatX>(MatX(spd)).eigenvalues()[0];
  SpMat I(n, n);
  I.setIdentity();
  const SpMat indefinite = spd - (lowest + 0.5) * I;
  EXPECT_FALSE(solver->factorize(indefinite));
  EXPECT_THROW(solver->solve(VecX::Ones(n)), Error);
  // Negative definite, and a matrix with a non-finite entry.
  EXPECT_FALSE(solver->factorize(SpMat(-1.0 * spd)));
  SpMat with_nan = randomSpd(n, 3, 22);
  with_nan.valuePtr()[0] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(solver->factorize(with_nan));
  // The solver recovers on the next positive definite matrix.
  const SpMat good = randomSpd(n, 3, 23);
  ASSERT_TRUE(solver->factorize(good));
  const VecX b = randomVector(n, 1);
  EXPECT_LT(relativeError(solver->solve(b), VecX(MatX(good).ldlt().solve(b))), 1e-10);
}

TEST_P(LinearSolverTest, RejectsBadShapesWithMessages) {
  auto solver = makeLinearSolver(GetParam(), 3);
  const std::string message = test::messageOf<InputError>([&] { solver->factorize(SpMat(3, 4)); });
  EXPECT_NE(message.find("square"), std::string::npos) << message;
  EXPECT_NE(message.find("(3, 4)"), std::string::npos) << message;
  ASSERT_TRUE(solver->factorize(randomSpd(3, 1, 2)));
  const std::string wrong_b = test::messageOf<InputError>([&] { solver->solve(VecX::Ones(5)); });
  EXPECT_NE(wrong_b.find("3 entries, got 5"), std::string::npos) << wrong_b;
}

// The dense solver factors in single precision where that suffices and refines its exact solves
// against the double matrix; ill-conditioned matrices get the double factor. Either way the
// solves are as accurate as a double Cholesky's, and the preconditioner stays within float
// precision of the exact solve.
TEST(DenseCholeskySolver, SolvesToDoubleAccuracyWellAndIllConditioned) {
  const int n = 120;
  std::mt19937 rng(17);
  std::normal_distribution<double> g(0.0, 1.0);
  MatX Q = MatX::NullaryExpr(n, n, [&]() { return g(rng); });
  Q = Eigen::HouseholderQR<MatX>(Q).householderQ();
  for (double condition : {1e2, 1e6, 1e12}) {
    SCOPED_TRACE("condition " + std::to_string(condition));
    VecX eigenvalues(n);
    for (int i = 0; i < n; ++i) eigenvalues[i] = std::pow(condition, -double(i) / (n - 1));
    const MatX A = Q * eigenvalues.asDiagonal() * Q.transpose();
    const VecX b = randomVector(n, 3);
    auto solver = makeLinearSolver(LinearSolverType::Dense, n);
    ASSERT_TRUE(solver->factorize(SpMat(A.sparseView())));
    const Eigen::LLT<MatX> reference(A);
    const VecX x_ref = reference.solve(b);
    const double ref_residual = (A * x_ref - b).norm() / b.norm();
    const VecX x = solver->solve(b);
    EXPECT_LE((A * x - b).norm() / b.norm(), 10 * ref_residual + 1e-14);
    EXPECT_LE(relativeError(x, x_ref), 1e-15 * condition + 1e-13);
    VecX preconditioned = b;
    solver->preconditionInPlace(preconditioned);
    EXPECT_LE(relativeError(preconditioned, x_ref), 1e-6 * condition);  // float precision
    VecX in_place = b;
    solver->solveInPlace(in_place);
    EXPECT_EQ(in_place, x);
  }
}

// The float factor's refinement must reach the double solve's accuracy on every system, not on
// the lucky ones: where it stops depends on the float rounding, which depends on the build's SIMD
// width (a fixed stopping threshold passed the test above on AVX2 and failed it on AVX-512). Many
// random systems sample that rounding on any host: the former threshold left 75 of 180 such
// systems more than 10× above the double solve's residual (up to 400×).
TEST(DenseCholeskySolver, RefinementReachesTheDoubleSolversResidualOnManySystems) {
  int systems = 0, worse = 0;
  double worst_ratio = 0.0;
  for (int n : {30, 120, 250}) {
    for (unsigned seed = 1; seed <= 8; ++seed) {
      std::mt19937 rng(seed * 7 + n);
      std::normal_distribution<double> g(0.0, 1.0);
      MatX Q = MatX::NullaryExpr(n, n, [&]() { return g(rng); });
      Q = Eigen::HouseholderQR<MatX>(Q).householderQ();
      const VecX b = VecX::NullaryExpr(n, [&]() { return g(rng); });
      for (double condition : {1e2, 1e4, 1e6}) {
        VecX eigenvalues(n);
        for (int i = 0; i < n; ++i) eigenvalues[i] = std::pow(condition, -double(i) / (n - 1));
        const MatX A = Q * eigenvalues.asDiagonal() * Q.transpose();
        const double ref_residual = (A * Eigen::LLT<MatX>(A).solve(b) - b).norm() / b.norm();
        auto solver = makeLinearSolver(LinearSolverType::Dense, n);
        ASSERT_TRUE(solver->factorize(SpMat(A.sparseView())));
        const double residual = (A * solver->solve(b) - b).norm() / b.norm();
        ASSERT_GT(residual, 0.0);
        ++systems;
        worst_ratio = std::max(worst_ratio, residual / ref_residual);
        if (residual > 10 * ref_residual + 1e-14) ++worse;
      }
    }
  }
  EXPECT_EQ(worse, 0) << "of " << systems << " systems; worst ratio " << worst_ratio;
}

INSTANTIATE_TEST_SUITE_P(Backends, LinearSolverTest,
                         ::testing::Values(LinearSolverType::Dense, LinearSolverType::Cholmod,
                                           LinearSolverType::SparseLLT),
                         [](const auto& info) {
                           return info.param == LinearSolverType::Dense     ? "Dense"
                                  : info.param == LinearSolverType::Cholmod ? "Cholmod"
                                                                            : "SparseLLT";
                         });

class SparseSolverTest : public ::testing::TestWithParam<LinearSolverType> {};

TEST_P(SparseSolverTest, ReusesTheAnalysisWhileThePatternIsUnchanged) {
  const int n = 200;
  auto solver = makeLinearSolver(GetParam(), n);
  SpMat A = randomSpd(n, 3, 7);
  const VecX b = randomVector(n, 8);
  for (int round = 0; round < 4; ++round) {
    // New values, same pattern.
    for (int k = 0; k < A.nonZeros(); ++k) A.valuePtr()[k] *= 1.1;
    A.diagonal().array() += 0.3;
    ASSERT_TRUE(solver->factorize(A));
    EXPECT_LT(relativeError(solver->solve(b), VecX(MatX(A).ldlt().solve(b))), 1e-10);
  }
  EXPECT_EQ(solver->numAnalyses(), 1);
  EXPECT_EQ(solver->numFactorizations(), 4);
  // A failed (indefinite) factorization with the same pattern keeps the analysis too.
  SpMat negative = -1.0 * A;
  EXPECT_FALSE(solver->factorize(negative));
  EXPECT_EQ(solver->numAnalyses(), 1);
  // A different pattern needs a new analysis.
  const SpMat B = randomSpd(n, 4, 9);
  ASSERT_TRUE(solver->factorize(B));
  EXPECT_EQ(solver->numAnalyses(), 2);
  EXPECT_LT(relativeError(solver->solve(b), VecX(MatX(B).ldlt().solve(b))), 1e-10);
  ASSERT_TRUE(solver->factorize(B));
  EXPECT_EQ(solver->numAnalyses(), 2);
  EXPECT_EQ(solver->numFactorizations(), 7);
}

INSTANTIATE_TEST_SUITE_P(Backends, SparseSolverTest,
                         ::testing::Values(LinearSolverType::Cholmod, LinearSolverType::SparseLLT),
                         [](const auto& info) {
                           return info.param == LinearSolverType::Cholmod ? "Cholmod" : "SparseLLT";
                         });

// CHOLMOD's factorization runs its own OpenMP loops on the calling thread (cholmod_solver.cpp:
// they asked for 4 threads per supernode) and leaves the OpenMP settings as it found them.
TEST(CholmodSolver, FactorsWithItsOpenMpLoopsSerialAndRestoresTheSettings) {
  const SpMat A = randomSpd(3000, 4, 11);
  auto solver = makeLinearSolver(LinearSolverType::Cholmod, int(A.rows()));
  for (int levels : {1, 3}) {
    omp_set_max_active_levels(levels);
    ASSERT_TRUE(solver->factorize(A));
    EXPECT_EQ(omp_get_max_active_levels(), levels);
    const VecX b = randomVector(int(A.rows()), 12);
    EXPECT_LE(relativeError(A * solver->solve(b), b), 1e-10);
  }
  omp_set_max_active_levels(1);
}

TEST(LinearSolverFactory, AutoPicksDenseForSmallAndCholmodForLargeSystems) {
  EXPECT_EQ(makeLinearSolver(LinearSolverType::Auto, 144)->name(), "dense-llt");
  EXPECT_EQ(makeLinearSolver(LinearSolverType::Auto, 600)->name(), "dense-llt");
  EXPECT_EQ(makeLinearSolver(LinearSolverType::Auto, 601)->name(), "cholmod-supernodal");
  EXPECT_EQ(makeLinearSolver(LinearSolverType::Auto, 50, 10)->name(), "cholmod-supernodal");
  EXPECT_EQ(makeLinearSolver(LinearSolverType::Dense, 5000)->name(), "dense-llt");
  EXPECT_EQ(makeLinearSolver(LinearSolverType::SparseLLT, 5)->name(), "eigen-simplicial-llt");
}

}  // namespace
}  // namespace flsh
