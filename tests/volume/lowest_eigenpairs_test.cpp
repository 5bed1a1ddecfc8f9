// The block Lanczos eigensolver of the vibration modes (volume/lowest_eigenpairs.h) and the
// CHOLMOD factor it runs on (volume/sparse_cholesky.h), against dense generalized eigensolves.
#include "volume/lowest_eigenpairs.h"

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <random>

#include "flsh/core/error.h"
#include "support/test_support.h"
#include "volume/sparse_cholesky.h"

namespace flsh::detail {
namespace {

using test::messageOf;

// A 2D grid Laplacian plus a random diagonal shift (sparse, SPD, clustered low spectrum) and
// random positive masses.
struct Pencil {
  SpMat K;
  VecX m;
};

Pencil gridPencil(int side, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uniform(0.5, 2.0);
  const int n = side * side;
  std::vector<Triplet> t;
  auto id = [side](int i, int j) { return i * side + j; };
  for (int i = 0; i < side; ++i)
    for (int j = 0; j < side; ++j) {
      t.emplace_back(id(i, j), id(i, j), 4.0 + 0.01 * uniform(rng));
      if (i + 1 < side) t.emplace_back(id(i, j), id(i + 1, j), -1.0);
      if (i > 0) t.emplace_back(id(i, j), id(i - 1, j), -1.0);
      if (j + 1 < side) t.emplace_back(id(i, j), id(i, j + 1), -1.0);
      if (j > 0) t.emplace_back(id(i, j), id(i, j - 1), -1.0);
    }
  Pencil p;
  p.K.resize(n, n);
  p.K.setFromTriplets(t.begin(), t.end());
  p.m.resize(n);
  for (int i = 0; i < n; ++i) p.m[i] = uniform(rng);
  return p;
}

TEST(LowestEigenpairs, MatchDenseGeneralizedEigenvalues) {
  const Pencil p = gridPencil(18, 5);  // 324 unknowns
  const SparseCholesky factor(p.K, "test");
  const int count = 25;
  const LowestEigenpairs e = lowestEigenpairs(p.K, factor, p.m, count);
  ASSERT_TRUE(e.converged);
  ASSERT_EQ(e.values.size(), count);
  const Eigen::GeneralizedSelfAdjointEigenSolver<MatX> dense(MatX(p.K), MatX(p.m.asDiagonal()));
  ASSERT_GT(dense.eigenvalues()[0], 0.0);
  for (int k = 0; k < count; ++k)
    EXPECT_NEAR(e.values[k], dense.eigenvalues()[k], 1e-9 * dense.eigenvalues()[k]) << k;
  const MatX G = e.vectors.transpose() * p.m.asDiagonal() * e.vectors;
  EXPECT_LT((G - MatX::Identity(count, count)).cwiseAbs().maxCoeff(), 1e-10);
  const MatX R = p.K * e.vectors - p.m.asDiagonal() * e.vectors * e.values.asDiagonal();
  for (int k = 0; k < count; ++k)
    EXPECT_LT(std::sqrt(R.col(k).cwiseAbs2().dot(p.m.cwiseInverse())), 1e-6 * e.values[k]);
  EXPECT_LE(e.max_residual, 1e-6);
  EXPECT_GT(e.solves, 0);
}

// A square grid's Laplacian with unit masses has eigenvalues of multiplicity 2 (the modes
// (a, b) and (b, a)): every block size, down to single vectors, must find both copies.
TEST(LowestEigenpairs, FindRepeatedEigenvaluesWithEveryBlockSize) {
  const int side = 14, n = side * side;
  std::vector<Triplet> t;
  for (int i = 0; i < side; ++i)
    for (int j = 0; j < side; ++j) {
      const int id = i * side + j;
      t.emplace_back(id, id, 4.0);
      if (i + 1 < side) t.emplace_back(id, id + side, -1.0), t.emplace_back(id + side, id, -1.0);
      if (j + 1 < side) t.emplace_back(id, id + 1, -1.0), t.emplace_back(id + 1, id, -1.0);
    }
  SpMat K(n, n);
  K.setFromTriplets(t.begin(), t.end());
  const VecX m = VecX::Ones(n);
  const SparseCholesky factor(K, "test");
  const Eigen::SelfAdjointEigenSolver<MatX> dense{MatX(K)};
  const int count = 12;
  ASSERT_NEAR(dense.eigenvalues()[1], dense.eigenvalues()[2], 1e-12);  // a repeated pair
  for (int block : {1, 2, 4, 8}) {
    LowestEigenpairsOptions options;
    options.block_size = block;
    options.max_columns = n;
    const LowestEigenpairs e = lowestEigenpairs(K, factor, m, count, options);
    ASSERT_TRUE(e.converged) << block << ": residual " << e.max_residual;
    ASSERT_EQ(e.values.size(), count);
    for (int k = 0; k < count; ++k)
      EXPECT_NEAR(e.values[k], dense.eigenvalues()[k], 1e-9 * dense.eigenvalues()[k])
          << "block " << block << ", pair " << k;
    EXPECT_GE(e.columns, count);
    EXPECT_GT(e.iterations, 0);
  }
}

// A Krylov space too small for the tolerance: the best pairs it has, reported as not converged.
TEST(LowestEigenpairs, ReportsNonConvergenceWithinTheLargestSpace) {
  const Pencil p = gridPencil(18, 7);
  const SparseCholesky factor(p.K, "test");
  LowestEigenpairsOptions options;
  options.max_columns = 24;
  options.tolerance = 1e-12;
  const LowestEigenpairs e = lowestEigenpairs(p.K, factor, p.m, 20, options);
  EXPECT_FALSE(e.converged);
  EXPECT_EQ(e.values.size(), 20);
  EXPECT_GT(e.max_residual, 1e-12);
  EXPECT_LE(e.columns, 24);
}

TEST(LowestEigenpairs, ZeroCountAndErrors) {
  const Pencil p = gridPencil(6, 1);
  const SparseCholesky factor(p.K, "test");
  EXPECT_EQ(lowestEigenpairs(p.K, factor, p.m, 0).values.size(), 0);
  EXPECT_NE(
      messageOf<InputError>([&] { lowestEigenpairs(p.K, factor, p.m, 37); }).find("count = 37"),
      std::string::npos);
  VecX bad = p.m;
  bad[3] = 0.0;
  EXPECT_NE(messageOf<InputError>([&] {
              lowestEigenpairs(p.K, factor, bad, 3);
            }).find("masses must be positive"),
            std::string::npos);
}

TEST(SparseCholesky, SolvesAndRefusesIndefiniteMatrices) {
  const Pencil p = gridPencil(10, 2);
  const SparseCholesky factor(p.K, "test");
  MatX B = MatX::Random(p.K.rows(), 300);  // more columns than one solve block
  const MatX X = factor.solve(B);
  EXPECT_LT((p.K * X - B).norm(), 1e-10 * B.norm());
  SpMat indefinite = p.K;
  indefinite.coeffRef(7, 7) = -50.0;
  EXPECT_NE(messageOf<Error>([&] {
              SparseCholesky(indefinite, "who");
            }).find("who: the 100 × 100 matrix is not positive definite"),
            std::string::npos);
  EXPECT_NE(
      messageOf<InputError>([&] { factor.solve(MatX::Zero(3, 1)); }).find("3 rows, expected 100"),
      std::string::npos);
}

TEST(MassOrthonormalize, DropsDependentColumnsAndKeepsTheSpan) {
  std::mt19937_64 rng(9);
  std::normal_distribution<double> normal;
  const int n = 50;
  MatX X(n, 6);
  for (Eigen::Index i = 0; i < X.size(); ++i) X.data()[i] = normal(rng);
  X.col(4) = 2.0 * X.col(1) - X.col(2);  // dependent
  X.col(5) = 1e6 * X.col(0);             // parallel, other scale
  VecX m = VecX::Constant(n, 0.5);
  m[0] = 3.0;
  const MatX Q = massOrthonormalize(X, m, 1e-10);
  ASSERT_EQ(Q.cols(), 4);
  EXPECT_LT((Q.transpose() * m.asDiagonal() * Q - MatX::Identity(4, 4)).cwiseAbs().maxCoeff(),
            1e-12);
  const MatX P = Q * (Q.transpose() * (m.asDiagonal() * X));
  EXPECT_LT((P - X).norm(), 1e-9 * X.norm());
  EXPECT_EQ(massOrthonormalize(X, m, 1e-10, 2).cols(), 2);
}

}  // namespace
}  // namespace flsh::detail
