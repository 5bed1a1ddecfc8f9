#include "volume/lowest_eigenpairs.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <random>
#include <string>

#include "flsh/core/error.h"

namespace flsh::detail {

MatX massOrthonormalize(const MatX& X, const VecX& m, double tolerance, int keep, bool normalize) {
  if (X.cols() == 0) return X;
  MatX Y = X;
  for (Eigen::Index c = 0; c < Y.cols() && normalize; ++c) {
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
// loses orthogonality once; twice is enough, Giraud et al. 2005). Returns the first pass's
// coefficients Vᵀ M W.
MatX orthogonalizeAgainst(const Eigen::Ref<const MatX>& V, const VecX& m, MatX& W) {
  MatX first = V.transpose() * (m.asDiagonal() * W);
  W.noalias() -= V * first;
  W.noalias() -= V * (V.transpose() * (m.asDiagonal() * W));
  return first;
}

// Relative residuals ‖Kx − λMx‖_{M⁻¹} / (λ ‖x‖_M) of M-orthonormal pairs.
double largestResidual(const SpMat& K, const VecX& m, const VecX& values, const MatX& X) {
  const MatX R = K * X - m.asDiagonal() * X * values.asDiagonal();
  const VecX inverse_m = m.cwiseInverse();
  double largest = 0.0;
  for (Eigen::Index i = 0; i < X.cols(); ++i)
    largest =
        std::max(largest, std::sqrt(R.col(i).cwiseAbs2().dot(inverse_m)) / std::abs(values[i]));
  return largest;
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
  if (options.block_size < 1 || options.max_columns < 0 || !(options.tolerance > 0.0))
    throw InputError(fn + "options: block_size ≥ 1, max_columns ≥ 0, tolerance > 0");
  LowestEigenpairs out;
  out.values.resize(0);
  out.vectors.resize(n, 0);
  if (count == 0) {
    out.converged = true;
    return out;
  }
  const Eigen::Index p = std::min<Eigen::Index>(n, options.block_size);
  const Eigen::Index cap =
      options.max_columns > 0
          ? std::min<Eigen::Index>(n, std::max<Eigen::Index>(options.max_columns, count))
          : std::min<Eigen::Index>(n, 10 * Eigen::Index(count) + 20 * p);
  std::mt19937_64 rng(options.seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  // Random columns (normal entries, from the seed).
  auto randomBlock = [&](Eigen::Index columns) {
    MatX Q(n, columns);
    for (Eigen::Index c = 0; c < Q.cols(); ++c)
      for (Eigen::Index r = 0; r < n; ++r) Q(r, c) = normal(rng);
    return Q;
  };

  const VecX inverse_m = m.cwiseInverse();
  MatX V(n, cap);  // the Krylov space's M-orthonormal columns [0, k)
  MatX T = MatX::Zero(cap, cap);
  const MatX block = massOrthonormalize(randomBlock(p), m, 1e-12);
  V.leftCols(block.cols()) = block;
  Eigen::Index k = block.cols();
  for (Eigen::Index last = 0;; ++out.iterations) {
    // W = K⁻¹ M V_last; T's columns of the last block from the first Gram–Schmidt pass.
    const Eigen::Index width = k - last;
    MatX W = factor.solve(m.asDiagonal() * V.middleCols(last, width));
    out.solves += int(width);
    const MatX C = orthogonalizeAgainst(V.leftCols(k), m, W);
    T.block(0, last, k, width) = C;
    T.block(last, 0, width, k) = C.transpose();
    T.block(last, last, width, width) =
        0.5 * (C.bottomRows(width) + C.bottomRows(width).transpose());
    // The next block: W's remainder, topped up with random directions if it lost rank.
    MatX next = massOrthonormalize(W, m, 1e-10);
    if (next.cols() < width && k + next.cols() < n) {
      MatX extra = randomBlock(std::min<Eigen::Index>(width - next.cols(), n - k - next.cols()));
      orthogonalizeAgainst(V.leftCols(k), m, extra);
      if (next.cols() > 0) orthogonalizeAgainst(next, m, extra);
      extra = massOrthonormalize(extra, m, 1e-10);
      MatX both(n, next.cols() + extra.cols());
      both << next, extra;
      next.swap(both);
    }
    // Ritz pairs (μ, x = Vy) of T, once the space can hold the pairs wanted and a block more: μ
    // largest ↔ λ = 1/μ smallest. Their residuals come from the Lanczos relation: K⁻¹Mx − μx =
    // V₊ B y_last =: r, so Kx − λMx = −λ K r and the relative residual ‖Kx − λMx‖_{M⁻¹} / λ is
    // ‖K r‖_{M⁻¹} (through G), exactly, without forming x.
    const bool full = next.cols() == 0 || k + next.cols() > cap;
    if (k >= count + p || full) {
      // B = V₊ᵀ M W (the Lanczos relation's coupling, W = V₊ B after the Gram–Schmidt passes);
      // G = (KV₊)ᵀ M⁻¹ (KV₊): ‖K V₊ c‖²_{M⁻¹} = cᵀ G c.
      const MatX B = next.transpose() * (m.asDiagonal() * W);
      const MatX KN = K * next;
      const MatX G = KN.transpose() * (inverse_m.asDiagonal() * KN);
      const Eigen::SelfAdjointEigenSolver<MatX> ritz(T.topLeftCorner(k, k));
      const Eigen::Index wanted = std::min<Eigen::Index>(count, k);
      double residual = 0.0;
      for (Eigen::Index i = 0; i < wanted; ++i) {
        const VecX c = B * ritz.eigenvectors().col(k - 1 - i).tail(width);
        residual = std::max(residual, std::sqrt(std::max(0.0, c.dot(G * c))));
      }
      if ((wanted == count && residual <= options.tolerance) || full) {
        // The wanted Ritz vectors, refined by Rayleigh–Ritz with K in their span (which can only
        // lower the Ritz values towards the eigenvalues), and their residuals measured.
        MatX Y(k, wanted);
        for (Eigen::Index i = 0; i < wanted; ++i) Y.col(i) = ritz.eigenvectors().col(k - 1 - i);
        const MatX X = V.leftCols(k) * Y;
        MatX A = X.transpose() * (K * X);
        A = 0.5 * (A + A.transpose());
        const Eigen::SelfAdjointEigenSolver<MatX> refined(A);
        out.values = refined.eigenvalues();
        out.vectors = X * refined.eigenvectors();
        out.max_residual = largestResidual(K, m, out.values, out.vectors);
        out.columns = int(k);
        out.converged = wanted == count && out.max_residual <= options.tolerance;
        if (out.converged || full) return out;
      }
    }
    V.middleCols(k, next.cols()) = next;
    last = k;
    k += next.cols();
  }
}

}  // namespace flsh::detail
