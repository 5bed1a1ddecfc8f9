// The lowest eigenpairs of a symmetric definite pencil K φ = λ M φ (K sparse positive definite
// and factored, M diagonal positive), for the fixed-interface vibration modes of the soft tissue
// (modal_basis). Private to src/volume.
//
// Method: block Krylov subspaces of the shift-inverted operator K⁻¹M (whose largest eigenvalues
// 1/λ are the pencil's smallest), built with full M-orthogonalization (twice, classical
// Gram–Schmidt) and followed by a Rayleigh–Ritz projection of K; each restart starts from the
// previous Ritz vectors (a block Lanczos with explicit restarts). Ritz values approach the
// eigenvalues from above and converge fastest at the low end, which is the end wanted here.
#pragma once

#include <cstdint>

#include "flsh/core/types.h"
#include "volume/sparse_cholesky.h"

namespace flsh::detail {

struct LowestEigenpairsOptions {
  /// Relative residual ‖Kφ − λMφ‖_{M⁻¹} / (λ ‖φ‖_M) each returned pair must reach.
  double tolerance = 1e-6;
  int max_restarts = 30;
  /// Extra columns of the block beyond the pairs wanted (≥ 1): they speed up the convergence of
  /// the highest wanted pairs.
  int extra_columns = 12;
  int krylov_blocks = 4;  ///< blocks per restart (≥ 2)
  std::uint64_t seed = 1;
};

struct LowestEigenpairs {
  VecX values;              ///< count ascending eigenvalues λ
  MatX vectors;             ///< n × count, M-orthonormal
  double max_residual = 0;  ///< largest relative residual of the returned pairs
  int restarts = 0;
  int solves = 0;  ///< columns solved with the factor
  bool converged = false;
};

/// `count` lowest eigenpairs of (K, diag(m)); `factor` is K's. Throws InputError for sizes that
/// do not match, count outside [0, n] or m not positive. Does not throw on non-convergence:
/// see `converged` and `max_residual`.
LowestEigenpairs lowestEigenpairs(const SpMat& K, const SparseCholesky& factor, const VecX& m,
                                  int count, const LowestEigenpairsOptions& options = {});

/// Columns of X made M-orthonormal (diag(m)), dropping those whose Gram eigenvalue is below
/// tolerance × the largest (after each column is M-normalized); the result spans the kept
/// directions ordered by decreasing Gram eigenvalue. `keep` > 0 keeps at most that many.
MatX massOrthonormalize(const MatX& X, const VecX& m, double tolerance, int keep = 0);

}  // namespace flsh::detail
