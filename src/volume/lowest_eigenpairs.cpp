#include "volume/lowest_eigenpairs.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <random>
#include <string>

#include "flsh/core/error.h"

namespace flsh::detail {

MatX massOrthonormalize(const MatX& X, const VecX& m, double tolerance, int keep) {
  if (X.cols() == 0) return X;
  MatX Y = X;
  for (Eigen::Index c = 0; c < Y.cols(); ++c) {
    const double norm = std::sqrt(Y.col(c).cwiseAbs2().dot(m));
    if (norm > 0.0) Y.col(c) /= norm;
  }
  const MatX G = Y.transpose() * m.asDiagonal() * Y;
  const Eigen::SelfAdjointEigenSolver<MatX> eig(0.5 * (G + G.transpose()));
  const VecX& w = eig.eigenvalues();  // ascending
  const double largest = w.maxCoeff();
  int kept = 0;
  for (Eigen::Index i = w.size() - 1; i >= 0 && w[i] > tolerance * largest; --i) ++kept;
  if (keep > 0) kept = std::min(kept, keep);
  MatX out(Y.rows(), kept);
  for (int k = 0; k < kept; ++k) {
    const Eigen::Index i = w.size() - 1 - k;
    out.col(k) = Y * (eig.eigenvectors().col(i) / std::sqrt(w[i]));
  }
  return out;
}

namespace {

// W minus its M-projection on the columns of V (M-orthonormal), twice (classical Gram–Schmidt
// loses orthogonality once; twice is enough, Giraud et al. 2005).
void orthogonalizeAgainst(const MatX& V, const VecX& m, MatX& W) {
  if (V.cols() == 0) return;
  for (int pass = 0; pass < 2; ++pass) W -= V * (V.transpose() * (m.asDiagonal() * W));
}

}  // namespace

LowestEigenpairs lowestEigenpairs(const SpMat& K, const SparseCholesky& factor, const VecX& m,
                                  int count, const LowestEigenpairsOptions& options) {
  const std::string fn = "lowestEigenpairs: ";
  const Eigen::Index n = K.rows();
  if (K.cols() != n || factor.rows() != n || m.size() != n)
    throw InputError(fn + "K is " + std::to_string(K.rows()) + " × " + std::to_string(K.cols()) +
                     ", its factor " + std::to_string(factor.rows()) + " rows and m " +
                     std::to_string(m.size()) + " entries, expected one size");
  if (count < 0 || count > n)
    throw InputError(fn + "count = " + std::to_string(count) + ", expected in [0, " +
                     std::to_string(n) + "]");
  if (!(m.minCoeff() > 0.0) || !m.allFinite())
    throw InputError(fn + "the masses must be positive and finite");
  if (options.extra_columns < 1 || options.krylov_blocks < 2 || options.max_restarts < 0)
    throw InputError(fn + "options: extra_columns ≥ 1, krylov_blocks ≥ 2, max_restarts ≥ 0");
  LowestEigenpairs out;
  out.values.resize(0);
  out.vectors.resize(n, 0);
  if (count == 0) {
    out.converged = true;
    return out;
  }
  const int block = int(std::min<Eigen::Index>(n, count + options.extra_columns));
  std::mt19937_64 rng(options.seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  MatX start(n, block);
  for (Eigen::Index c = 0; c < start.cols(); ++c)
    for (Eigen::Index r = 0; r < n; ++r) start(r, c) = normal(rng);
  const VecX inverse_m = m.cwiseInverse();

  for (int restart = 0;; ++restart) {
    // The Krylov space [Q, (K⁻¹M) Q, (K⁻¹M)² Q, ...], M-orthonormal.
    MatX V = massOrthonormalize(start, m, 1e-12);
    MatX last = V;
    for (int b = 1; b < options.krylov_blocks && V.cols() < n; ++b) {
      MatX W = factor.solve(m.asDiagonal() * last);
      out.solves += int(last.cols());
      orthogonalizeAgainst(V, m, W);
      // Combinations of W's columns stay ⟂ V (to rounding; the Rayleigh–Ritz step below does
      // not need more than that).
      W = massOrthonormalize(W, m, 1e-10);
      if (W.cols() == 0) break;
      MatX grown(n, V.cols() + W.cols());
      grown << V, W;
      V.swap(grown);
      last = std::move(W);
    }
    // Rayleigh–Ritz: VᵀKV y = θ y (VᵀMV = I).
    const MatX KV = K * V;
    MatX A = V.transpose() * KV;
    A = 0.5 * (A + A.transpose());
    const Eigen::SelfAdjointEigenSolver<MatX> ritz(A);
    const int wanted = int(std::min<Eigen::Index>(count, V.cols()));
    const int next = int(std::min<Eigen::Index>(block, V.cols()));
    const MatX Y = ritz.eigenvectors().leftCols(next);
    MatX X = V * Y;
    const MatX KX = KV * Y;
    out.max_residual = 0.0;
    for (int i = 0; i < wanted; ++i) {
      const double theta = ritz.eigenvalues()[i];
      const VecX r = KX.col(i) - theta * m.cwiseProduct(X.col(i));
      const double residual = std::sqrt(r.cwiseAbs2().dot(inverse_m)) / std::abs(theta);
      out.max_residual = std::max(out.max_residual, residual);
    }
    out.restarts = restart;
    if ((wanted == count && out.max_residual <= options.tolerance) ||
        restart >= options.max_restarts) {
      out.converged = wanted == count && out.max_residual <= options.tolerance;
      out.values = ritz.eigenvalues().head(wanted);
      out.vectors = X.leftCols(wanted);
      return out;
    }
    start = std::move(X);
  }
}

}  // namespace flsh::detail
