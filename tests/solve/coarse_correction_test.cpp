// The lagged PCG's coarse level (src/solve/coarse_correction.h): the balancing two-level
// preconditioner P = (I − QH) M⁻¹ (I − HQ) + Q with Q = Z E⁻¹ Zᵀ, E = Zᵀ H Z, on random sparse
// SPD matrices: it is H⁻¹ when M⁻¹ is, it solves residuals in H·span(Z) exactly whatever M is,
// it is symmetric positive definite for a poor M, and it switches itself off without coarse
// DoFs or when their block is not positive definite.
#include "solve/coarse_correction.h"

#include <gtest/gtest.h>
#include <omp.h>

#include <Eigen/Dense>
#include <random>
#include <vector>

namespace flsh {
namespace {

using detail::CoarseCorrection;

/// A random sparse SPD matrix (n × n, full storage, compressed): a banded random coupling made
/// diagonally dominant, with a dense coarse-like block on `dense` (every pair coupled).
SpMat randomSpd(int n, const std::vector<int>& dense, unsigned seed, int stride = 5) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> value(-1.0, 1.0);
  MatX A = MatX::Zero(n, n);
  for (int i = 0; i < n; ++i)
    for (int j = i + 1; j < std::min(n, i + 4); ++j) A(i, j) = A(j, i) = value(rng);
  for (int i : dense)
    for (int j : dense)
      if (i < j) A(i, j) = A(j, i) = value(rng);
  for (int i : dense)  // the coarse DoFs couple to everything, like bones to their nodes
    for (int j = 0; j < n; j += stride)
      if (i != j) A(i, j) = A(j, i) = 0.5 * value(rng);
  for (int i = 0; i < n; ++i) A(i, i) = A.row(i).cwiseAbs().sum() + 0.5;
  SpMat S = A.sparseView();
  S.makeCompressed();
  return S;
}

/// P as a dense matrix, column by column, with M⁻¹ the dense matrix Minv.
MatX denseP(const CoarseCorrection& coarse, const MatX& Minv) {
  const Eigen::Index n = Minv.rows();
  MatX P(n, n);
  for (Eigen::Index c = 0; c < n; ++c) {
    VecX v = VecX::Unit(n, c);
    coarse.apply(v, [&](VecX& x) { x = Minv * x; });
    P.col(c) = v;
  }
  return P;
}

const std::vector<int> kCoarse = {0, 1, 2, 7, 20, 33};
constexpr int kN = 60;

TEST(CoarseCorrection, IsTheInverseWhenTheFactorIsExact) {
  const SpMat H = randomSpd(kN, kCoarse, 1);
  CoarseCorrection coarse;
  ASSERT_TRUE(coarse.build(H, kCoarse));
  ASSERT_TRUE(coarse.active());
  const MatX Hinv = MatX(H).inverse();
  const MatX P = denseP(coarse, Hinv);
  ASSERT_GT(P.norm(), 0.0);
  EXPECT_LE((P - Hinv).norm(), 1e-10 * Hinv.norm());
}

TEST(CoarseCorrection, SolvesResidualsInTheCoarseSpanExactly) {
  const SpMat H = randomSpd(kN, kCoarse, 2);
  CoarseCorrection coarse;
  ASSERT_TRUE(coarse.build(H, kCoarse));
  // A poor factor: the inverse diagonal.
  const MatX Minv = MatX(H).diagonal().cwiseInverse().asDiagonal();
  VecX c = VecX::Zero(kN);
  for (size_t k = 0; k < kCoarse.size(); ++k) c[kCoarse[k]] = 0.3 + 0.1 * double(k);
  VecX r = H * c;  // r = H Z c
  coarse.apply(r, [&](VecX& x) { x = Minv * x; });
  EXPECT_LE((r - c).norm(), 1e-12 * c.norm());
  // M alone does not: the coarse level is doing the work.
  EXPECT_GT((Minv * (H * c) - c).norm(), 0.1 * c.norm());
}

TEST(CoarseCorrection, IsSymmetricPositiveDefiniteForAPoorFactor) {
  const SpMat H = randomSpd(kN, kCoarse, 3);
  CoarseCorrection coarse;
  ASSERT_TRUE(coarse.build(H, kCoarse));
  // M: the Hessian with its coarse rows and columns from another matrix (a stale factor).
  MatX M = MatX(H);
  const MatX other = MatX(randomSpd(kN, kCoarse, 4));
  for (int i : kCoarse) {
    M.row(i) = other.row(i);
    M.col(i) = other.col(i);
  }
  M.diagonal().array() += 2.0;
  ASSERT_GT(Eigen::SelfAdjointEigenSolver<MatX>(M).eigenvalues().minCoeff(), 0.0);
  const MatX P = denseP(coarse, M.inverse());
  EXPECT_LE((P - P.transpose()).norm(), 1e-12 * P.norm());
  EXPECT_GT(Eigen::SelfAdjointEigenSolver<MatX>(0.5 * (P + P.transpose())).eigenvalues().minCoeff(),
            0.0);
  // The preconditioned operator's spectrum is tighter with the coarse level than with M alone.
  const auto condition = [](const MatX& A) {
    const VecX ev = A.eigenvalues().real();
    return ev.maxCoeff() / ev.minCoeff();
  };
  EXPECT_LT(condition(P * MatX(H)), condition(M.inverse() * MatX(H)));
}

// Coarse columns long enough for the two-thread products (> 50 000 entries, as an avatar's
// bones): the same numbers bit for bit on one thread and on two, and the formula's.
TEST(CoarseCorrection, LongColumnsGiveTheSameNumbersOnOneAndTwoThreads) {
  constexpr int n = 2000;
  std::vector<int> coarse_dofs;
  for (int k = 0; k < 60; ++k) coarse_dofs.push_back(3 + 31 * k);
  const SpMat H = randomSpd(n, coarse_dofs, 5, 2);
  long entries = 0;
  for (int d : coarse_dofs) entries += H.outerIndexPtr()[d + 1] - H.outerIndexPtr()[d];
  ASSERT_GT(entries, 50000);
  CoarseCorrection coarse;
  ASSERT_TRUE(coarse.build(H, coarse_dofs));
  const MatX Hd(H);
  const VecX diagonal_inverse = Hd.diagonal().cwiseInverse();  // a poor M⁻¹: Jacobi
  const auto jacobi = [&](VecX& x) { x = diagonal_inverse.cwiseProduct(x); };
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> value(-1.0, 1.0);
  VecX r(n);
  for (int i = 0; i < n; ++i) r[i] = value(rng);
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  VecX one = r;
  coarse.apply(one, jacobi);
  omp_set_num_threads(2);
  VecX two = r;
  coarse.apply(two, jacobi);
  omp_set_num_threads(threads);
  ASSERT_GT(one.norm(), 0.0);
  EXPECT_EQ(one, two);
  // P r = (I − QH) M⁻¹ (I − HQ) r + Q r.
  const Eigen::Index m = Eigen::Index(coarse_dofs.size());
  MatX Z = MatX::Zero(n, m);
  for (Eigen::Index k = 0; k < m; ++k) Z(coarse_dofs[size_t(k)], k) = 1.0;
  const MatX E = Z.transpose() * Hd * Z;
  const Eigen::LLT<MatX> llt(E);
  const VecX Qr = Z * llt.solve(Z.transpose() * r);
  const VecX v = diagonal_inverse.cwiseProduct(r - Hd * Qr);
  const VecX expected = v - Z * llt.solve(Z.transpose() * (Hd * v)) + Qr;
  EXPECT_LT((one - expected).norm(), 1e-12 * expected.norm());
}

TEST(CoarseCorrection, SwitchesOffWithoutCoarseDofsOrWhenTheirBlockIsIndefinite) {
  SpMat H = randomSpd(kN, kCoarse, 5);
  CoarseCorrection coarse;
  EXPECT_FALSE(coarse.build(H, {}));
  EXPECT_FALSE(coarse.active());
  H.coeffRef(kCoarse[2], kCoarse[2]) = -1.0;  // an indefinite coarse block
  EXPECT_FALSE(coarse.build(H, kCoarse));
  EXPECT_FALSE(coarse.active());
}

}  // namespace
}  // namespace flsh
