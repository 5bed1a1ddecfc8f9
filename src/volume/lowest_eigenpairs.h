// The lowest eigenpairs of a symmetric definite pencil K φ = λ M φ (K sparse positive definite
// and factored, M diagonal positive), for the fixed-interface vibration modes of the soft tissue
// (modal_basis). Private to src/volume.
//
// Method: a block Lanczos process on the shift-inverted operator K⁻¹M (whose largest eigenvalues
// 1/λ are the pencil's smallest), without restarts: the Krylov space [Q, K⁻¹MQ, (K⁻¹M)²Q, ...]
// grows block by block, each new block M-orthogonalized against all before it (twice,
// classical Gram–Schmidt, as BLAS-3 products). The projection T = Vᵀ M K⁻¹ M V is read off the
// first Gram–Schmidt pass, so each step costs one block solve and O(n k p) products; its
// eigenpairs and the Lanczos relation K⁻¹MV = VT + V₊B Eₛᵀ estimate every Ritz pair's residual
// for free. When the estimates of the wanted pairs are small, their true residuals are measured
// (after a Rayleigh–Ritz refinement with K in their span) and the process stops if they meet the
// tolerance. The low end, the end wanted, converges first; no Ritz vector is ever recomputed,
// which is what made the earlier restarted block Krylov solver 5–10× slower (docs/benchmarks.md).
#pragma once

#include <cstdint>

#include "flsh/core/types.h"
#include "volume/sparse_cholesky.h"

namespace flsh::detail {

struct LowestEigenpairsOptions {
  /// Relative residual ‖Kφ − λMφ‖_{M⁻¹} / (λ ‖φ‖_M) each returned pair must reach.
  double tolerance = 1e-6;
  /// Columns of each Lanczos block (≥ 1): larger blocks amortize the triangular solves and run
  /// the products as BLAS-3, smaller ones build a smaller space for the same pairs.
  int block_size = 4;
  /// Largest Krylov space (columns); 0: min(n, 10 · count + 20 · block_size). The process stops
  /// there, not converged, if the pairs have not met the tolerance.
  int max_columns = 0;
  std::uint64_t seed = 1;  ///< of the random starting block
};

struct LowestEigenpairs {
  VecX values;              ///< count ascending eigenvalues λ
  MatX vectors;             ///< n × count, M-orthonormal
  double max_residual = 0;  ///< largest relative residual of the returned pairs
  int iterations = 0;       ///< Lanczos block steps
  int columns = 0;          ///< size of the Krylov space at the end
  int solves = 0;           ///< columns solved with the factor
  bool converged = false;
};

/// `count` lowest eigenpairs of (K, diag(m)); `factor` is K's. Throws InputError for sizes that
/// do not match, count outside [0, n] or m not positive. Does not throw on non-convergence:
/// see `converged` and `max_residual`.
LowestEigenpairs lowestEigenpairs(const SpMat& K, const SparseCholesky& factor, const VecX& m,
                                  int count, const LowestEigenpairsOptions& options = {});

/// Columns of X made M-orthonormal (diag(m)), dropping those whose Gram eigenvalue is below
/// tolerance × the largest (after each column is M-normalized, unless `normalize` is off: then
/// the columns' own sizes weigh them); the result spans the kept directions ordered by
/// decreasing Gram eigenvalue (a mass-PCA). `keep` > 0 keeps at most that many.
MatX massOrthonormalize(const MatX& X, const VecX& m, double tolerance, int keep = 0,
                        bool normalize = true);

}  // namespace flsh::detail
