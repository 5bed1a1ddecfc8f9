// One interface over the linear solvers of Newton and of the adjoint: dense Cholesky for small
// systems, CHOLMOD (supernodal Cholesky) for large sparse ones. The symbolic analysis is cached
// and reused while the sparsity pattern does not change; the numeric factor stays available
// for later solves (the adjoint reuses it).
#pragma once

#include <memory>
#include <string>

#include "flsh/core/types.h"

namespace flsh {

enum class LinearSolverType {
  Auto,  ///< dense below `dense_threshold` unknowns, CHOLMOD above
  /// Dense Cholesky (positive definite only): the factor in single precision with exact solves
  /// refined to double accuracy, or in double where single precision does not suffice.
  Dense,
  Cholmod,  ///< CHOLMOD supernodal Cholesky (positive definite only)
  /// Eigen's simplicial (up-looking) Cholesky with AMD ordering: for small sparse systems such
  /// as the skeleton's block-tree Hessians, where dense or supernodal factors waste work.
  SparseLLT,
};

class LinearSolver {
 public:
  virtual ~LinearSolver() = default;
  /// Factors the symmetric matrix A (full storage, both triangles). Returns false if A is not
  /// positive definite (Newton then regularizes). Reuses the symbolic analysis when A has the
  /// same pattern as the previous call.
  virtual bool factorize(const SpMat& A) = 0;
  /// Solves A x = b with the factor of the last factorize() call. Throws Error if that call
  /// failed or there was none, or InputError if b has the wrong size.
  virtual VecX solve(const VecX& b) const = 0;
  /// solve() writing x over b (no result allocation: PCG calls it once per iteration).
  virtual void solveInPlace(VecX& b) const { b = solve(b); }
  /// b ← M⁻¹ b with M ≈ the factored matrix, for preconditioning (PCG on a lagged factor): by
  /// default the exact solveInPlace(). CHOLMOD's solver runs it on a single-precision copy of
  /// its factor, split over the OpenMP threads along the elimination tree (3–6× faster per
  /// solve on the 27 k-DoF FEM Hessian; relative difference from solve() ~1e-7 × cond(L)); the
  /// dense solver on a single-precision copy of its factor. Same errors as solveInPlace().
  virtual void preconditionInPlace(VecX& b) const { solveInPlace(b); }
  /// True while the last factorize() succeeded: solve() then uses that factor. A failed
  /// factorize() drops it. The factor persists across newtonSolve calls (lagged preconditioner).
  virtual bool hasFactor() const = 0;
  /// Unknowns of the held factor (0 without one).
  virtual int factorRows() const = 0;
  virtual std::string name() const = 0;
  /// Counters, for benchmarks: numeric factorizations and symbolic analyses done.
  int numFactorizations() const { return factorizations_; }
  int numAnalyses() const { return analyses_; }
  /// Newton's lagged mode marks the held factor stale when it preconditioned a PCG solve poorly,
  /// so that the next direction refactors; kept here because the lag spans newtonSolve calls.
  bool factorStale() const { return factor_stale_; }
  void setFactorStale(bool stale) { factor_stale_ = stale; }

 protected:
  int factorizations_ = 0;
  int analyses_ = 0;
  bool factor_stale_ = false;
};

/// Creates a solver; Auto picks Dense when n ≤ dense_threshold.
std::unique_ptr<LinearSolver> makeLinearSolver(LinearSolverType type, int n,
                                               int dense_threshold = 600);

}  // namespace flsh
