// The single-precision supernodal preconditioner of the CHOLMOD solver
// (LinearSolver::preconditionInPlace): it matches the double-precision solve to float
// accuracy, serially and split over two or three threads along the elimination tree, follows
// refactorizations, and rejects calls without a factor or with a wrong size. The dense solver's
// single-precision preconditioner too; the simplicial one applies its exact solve.
#include <gtest/gtest.h>
#include <omp.h>

#include <random>

#include "flsh/core/error.h"
#include "flsh/solve/linear_solver.h"
#include "solve/linear_solver_detail.h"
#include "support/test_support.h"

namespace flsh {
namespace {

/// 7-point Laplacian of an nx × ny × nz grid with varying edge weights plus shift·I: the kind
/// of pattern (a 3D mesh) whose nested-dissection elimination tree splits into big subtrees.
SpMat gridLaplacian(int nx, int ny, int nz, unsigned seed, double shift) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> weight(0.5, 2.0);
  const int n = nx * ny * nz;
  auto id = [&](int i, int j, int k) { return (k * ny + j) * nx + i; };
  std::vector<Triplet> t;
  VecX diagonal = VecX::Constant(n, shift);
  auto edge = [&](int a, int b) {
    const double w = weight(rng);
    t.emplace_back(a, b, -w);
    t.emplace_back(b, a, -w);
    diagonal[a] += w;
    diagonal[b] += w;
  };
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        if (i + 1 < nx) edge(id(i, j, k), id(i + 1, j, k));
        if (j + 1 < ny) edge(id(i, j, k), id(i, j + 1, k));
        if (k + 1 < nz) edge(id(i, j, k), id(i, j, k + 1));
      }
  for (int a = 0; a < n; ++a) t.emplace_back(a, a, diagonal[a]);
  SpMat A(n, n);
  A.setFromTriplets(t.begin(), t.end());
  A.makeCompressed();
  return A;
}

/// Runs f with OpenMP limited to `threads` threads, restoring the limit afterwards.
template <class F>
void withThreads(int threads, F f) {
  const int before = omp_get_max_threads();
  omp_set_num_threads(threads);
  f();
  omp_set_num_threads(before);
}

TEST(SupernodalPreconditioner, MatchesTheDoubleSolveSeriallyAndSplitOverThreads) {
  const SpMat A = gridLaplacian(18, 16, 14, 3, 1e-2);
  const int n = int(A.rows());
  const VecX b = test::randomVector(n, 1.0, 4);
  for (int threads : {1, 2, 3}) {
    withThreads(threads, [&] {
      auto solver = makeLinearSolver(LinearSolverType::Cholmod, n);
      ASSERT_TRUE(solver->factorize(A));
      const VecX exact = solver->solve(b);
      ASSERT_GT(exact.norm(), 0.0);
      VecX x = b;
      solver->preconditionInPlace(x);
      const double error = (x - exact).norm() / exact.norm();
      EXPECT_LT(error, 1e-4) << threads << " threads";
      EXPECT_GT(error, 0.0) << "the float copy cannot be bitwise the double solve";
      // A second right-hand side with the same copy.
      const VecX b2 = A * test::randomVector(n, 1.0, 5);
      VecX x2 = b2;
      solver->preconditionInPlace(x2);
      EXPECT_LT((x2 - solver->solve(b2)).norm() / x2.norm(), 1e-4);
      const detail::PreconditionerSplit split = detail::preconditionerSplit(*solver);
      EXPECT_EQ(split.threads, threads);
      if (threads > 1) {
        // The top of the tree (the separators above the split) is solved by one thread.
        EXPECT_GT(split.serial_share, 0.0);
        EXPECT_LT(split.serial_share, 0.5);
      } else {
        EXPECT_EQ(split.serial_share, 1.0);
      }
    });
  }
}

TEST(SupernodalPreconditioner, TwoThreadsGiveTheSerialResultUpToRounding) {
  const SpMat A = gridLaplacian(20, 12, 12, 8, 1e-1);
  const int n = int(A.rows());
  const VecX b = test::randomVector(n, 1.0, 9);
  VecX serial = b, split = b;
  withThreads(1, [&] {
    auto solver = makeLinearSolver(LinearSolverType::Cholmod, n);
    ASSERT_TRUE(solver->factorize(A));
    solver->preconditionInPlace(serial);
  });
  withThreads(2, [&] {
    auto solver = makeLinearSolver(LinearSolverType::Cholmod, n);
    ASSERT_TRUE(solver->factorize(A));
    solver->preconditionInPlace(split);
    ASSERT_EQ(detail::preconditionerSplit(*solver).threads, 2);
  });
  ASSERT_GT(serial.norm(), 0.0);
  // Float sums in another order: differences at float rounding, not more.
  EXPECT_LT((split - serial).norm() / serial.norm(), 1e-5);
}

TEST(SupernodalPreconditioner, FollowsEachNewFactor) {
  SpMat A = gridLaplacian(10, 10, 10, 12, 1e-2);
  const int n = int(A.rows());
  const VecX b = test::randomVector(n, 1.0, 13);
  auto solver = makeLinearSolver(LinearSolverType::Cholmod, n);
  for (int round = 0; round < 3; ++round) {
    // Same pattern, new values: the copy must be rebuilt from the new factor.
    for (int k = 0; k < A.nonZeros(); ++k) A.valuePtr()[k] *= 1.0 + 0.5 * round;
    A.diagonal().array() += 0.2 * round;
    ASSERT_TRUE(solver->factorize(A));
    VecX x = b;
    solver->preconditionInPlace(x);
    const VecX exact = solver->solve(b);
    EXPECT_LT((x - exact).norm() / exact.norm(), 1e-4) << "round " << round;
    EXPECT_LT((A * x - b).norm() / b.norm(), 1e-3) << "round " << round;
  }
  EXPECT_EQ(solver->numAnalyses(), 1);
}

TEST(SupernodalPreconditioner, RejectsCallsWithoutAFactorAndWrongSizes) {
  const SpMat A = gridLaplacian(6, 5, 4, 1, 1.0);
  auto solver = makeLinearSolver(LinearSolverType::Cholmod, int(A.rows()));
  VecX b = VecX::Ones(A.rows());
  const std::string no_factor = test::messageOf<Error>([&] { solver->preconditionInPlace(b); });
  EXPECT_NE(no_factor.find("no factor"), std::string::npos) << no_factor;
  ASSERT_TRUE(solver->factorize(A));
  VecX wrong = VecX::Ones(7);
  const std::string wrong_size =
      test::messageOf<InputError>([&] { solver->preconditionInPlace(wrong); });
  EXPECT_NE(wrong_size.find("120 entries, got 7"), std::string::npos) << wrong_size;
  // A failed factorization drops the factor, and with it the copy.
  EXPECT_FALSE(solver->factorize(SpMat(-1.0 * A)));
  EXPECT_THROW(solver->preconditionInPlace(b), Error);
}

TEST(SupernodalPreconditioner, SparseLltAppliesItsExactSolve) {
  const SpMat A = gridLaplacian(5, 4, 3, 2, 1.0);
  const VecX b = test::randomVector(int(A.rows()), 1.0, 3);
  auto solver = makeLinearSolver(LinearSolverType::SparseLLT, int(A.rows()));
  ASSERT_TRUE(solver->factorize(A));
  VecX x = b;
  solver->preconditionInPlace(x);
  EXPECT_EQ(x, solver->solve(b));
  EXPECT_EQ(detail::preconditionerSplit(*solver).threads, 0);
}

// The dense solver's preconditioner: its factor's solves in single precision, following each
// new factor, with the exact solve's errors.
TEST(DensePreconditioner, IsTheSolveInSinglePrecisionAndFollowsEachFactor) {
  SpMat A = gridLaplacian(8, 7, 6, 4, 1e-2);
  const int n = int(A.rows());
  const VecX b = test::randomVector(n, 1.0, 5);
  auto solver = makeLinearSolver(LinearSolverType::Dense, n);
  VecX none = b;
  const std::string no_factor = test::messageOf<Error>([&] { solver->preconditionInPlace(none); });
  EXPECT_NE(no_factor.find("no factor"), std::string::npos) << no_factor;
  for (int round = 0; round < 3; ++round) {
    for (int k = 0; k < A.nonZeros(); ++k) A.valuePtr()[k] *= 1.0 + 0.5 * round;
    A.diagonal().array() += 0.2 * round;
    ASSERT_TRUE(solver->factorize(A));
    VecX x = b;
    solver->preconditionInPlace(x);
    const VecX exact = solver->solve(b);
    ASSERT_GT(exact.norm(), 0.0);
    const double difference = (x - exact).norm() / exact.norm();
    EXPECT_GT(difference, 0.0) << "round " << round;  // single precision, not the double solve
    EXPECT_LT(difference, 1e-4) << "round " << round;
  }
  VecX wrong = VecX::Ones(7);
  const std::string wrong_size =
      test::messageOf<InputError>([&] { solver->preconditionInPlace(wrong); });
  EXPECT_NE(wrong_size.find("got 7"), std::string::npos) << wrong_size;
  EXPECT_FALSE(solver->factorize(SpMat(-1.0 * A)));
  EXPECT_THROW(solver->preconditionInPlace(none), Error);
}

}  // namespace
}  // namespace flsh
