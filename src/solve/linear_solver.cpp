#include "flsh/solve/linear_solver.h"

#include <Eigen/Cholesky>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "flsh/core/error.h"
#include "solve/linear_solver_detail.h"

namespace flsh {

namespace detail {

void checkSquare(const SpMat& A, const char* who) {
  if (A.rows() != A.cols() || A.rows() == 0)
    throw InputError(std::string(who) + ": matrix A must be square and non-empty, got " +
                     shapeString({long(A.rows()), long(A.cols())}));
}

bool allFinite(const SpMat& A) {
  const double* v = A.valuePtr();
  const Eigen::Index nnz = A.isCompressed() ? A.nonZeros() : A.data().size();
  for (Eigen::Index k = 0; k < nnz; ++k)
    if (!std::isfinite(v[k])) return false;
  return true;
}

}  // namespace detail

namespace {

// Pivots below this fraction of the largest one count as "not positive definite": the matrix is
// then singular to working precision and its Newton direction would be meaningless.
constexpr double kRelativePivotFloor = 1e-14;

/// Dense Cholesky of the lower triangle. The dense copy and the factor keep their storage
/// between calls of the same size (Newton calls it with one n every iteration).
/// The factor is computed in single precision where that suffices (twice the SIMD width: 0.60
/// against 0.85 ms for 405 DoFs) and exact solves refine it against the double matrix (a few
/// products with A) to double accuracy; where single precision does not suffice (the float
/// Cholesky fails, its pivots span more than kFloatPivotRatio, or the refinement stalls) the
/// factor is computed in double, as before.
class DenseCholeskySolver final : public LinearSolver {
 public:
  bool factorize(const SpMat& A) override {
    detail::checkSquare(A, "DenseCholeskySolver::factorize");
    has_factor_ = false;
    ++factorizations_;
    const Eigen::Index n = A.rows();
    if (dense_.rows() != n) {
      dense_.resize(n, n);
      ++analyses_;  // the "analysis" of a dense solver is sizing its storage
    }
    if (A.isCompressed() && A.nonZeros() == n * n) {
      // Full n × n pattern (Scene's dense storage): compressed columns hold the rows 0..n−1 in
      // order, so the values are the column-major dense matrix.
      dense_ = Eigen::Map<const MatX>(A.valuePtr(), n, n);
    } else {
      dense_.setZero();
      for (int k = 0; k < A.outerSize(); ++k)
        for (SpMat::InnerIterator it(A, k); it; ++it)
          if (it.row() >= it.col()) dense_(it.row(), it.col()) = it.value();
    }
    if (!dense_.allFinite()) return false;
    largest_diagonal_ = dense_.diagonal().cwiseAbs().maxCoeff();
    single_ = false;
    float_factor_.resize(0, 0);
    float_llt_.compute(dense_.cast<float>());  // reads the lower triangle only
    if (float_llt_.info() == Eigen::Success) {
      const Eigen::VectorXf pivots = float_llt_.matrixLLT().diagonal();
      single_ = pivots.minCoeff() > kFloatPivotRatio * pivots.maxCoeff();
    }
    has_factor_ = single_ || factorDouble();
    return has_factor_;
  }

  /// The factor's triangular solves in single precision (the float factor, or a float copy of
  /// the double one made on the first use after each factorization): half the memory traffic
  /// and twice the SIMD width of the double solves, for a preconditioner ~1e-7 relative from
  /// the exact solve.
  void preconditionInPlace(VecX& b) const override {
    if (!has_factor_ || b.size() != dense_.rows()) {
      solveInPlace(b);  // throws the same errors
      return;
    }
    float_rhs_ = b.cast<float>();
    if (single_) {
      float_llt_.solveInPlace(float_rhs_);
    } else {
      if (float_factor_.rows() != dense_.rows())
        float_factor_ =
            llt_.matrixLLT().triangularView<Eigen::Lower>().toDenseMatrix().cast<float>();
      float_factor_.triangularView<Eigen::Lower>().solveInPlace(float_rhs_);
      float_factor_.transpose().triangularView<Eigen::Upper>().solveInPlace(float_rhs_);
    }
    b = float_rhs_.cast<double>();
  }

  VecX solve(const VecX& b) const override {
    if (!has_factor_)
      throw Error(
          "DenseCholeskySolver::solve: no factor (the last factorize() failed or was "
          "never called)");
    if (b.size() != dense_.rows())
      throw InputError("DenseCholeskySolver::solve: b must have " + std::to_string(dense_.rows()) +
                       " entries, got " + std::to_string(b.size()));
    VecX x = b;
    solveInPlace(x);
    return x;
  }

  void solveInPlace(VecX& b) const override {
    if (!has_factor_ || b.size() != dense_.rows()) {
      b = solve(b);  // throws the same errors as solve()
      return;
    }
    if (single_ && refine(b)) return;
    if (single_) {  // the refinement stalled: the double factor from here on
      single_ = false;
      if (!factorDouble()) throw Error("DenseCholeskySolver::solve: the double factor failed");
    }
    llt_.solveInPlace(b);
  }

  bool hasFactor() const override { return has_factor_; }
  int factorRows() const override { return has_factor_ ? int(dense_.rows()) : 0; }

  std::string name() const override { return "dense-llt"; }

 private:
  // Float pivots spanning more than this (condition ≳ 1e8 relative to float's 1e-7 precision)
  // leave the refinement too little to work with: the factor is then computed in double.
  static constexpr float kFloatPivotRatio = 1e-3f;

  bool factorDouble() const {
    float_factor_.resize(0, 0);
    llt_.compute(dense_);  // reads the lower triangle only
    if (llt_.info() != Eigen::Success) return false;
    const auto pivots = llt_.matrixLLT().diagonal();
    return pivots.minCoeff() > std::sqrt(kRelativePivotFloor) * pivots.maxCoeff();
  }

  // Iterative refinement of the float solve against the double matrix, x ← x + M⁻¹(b − A x),
  // run to convergence: while each step at least halves the residual. It then sits at the
  // round-off of the residual's own evaluation, as a double solve does (within ~2.5× of the
  // double factor's residual on random SPD systems up to condition 1e6 and n = 405). A rule that
  // stopped at a fixed threshold (n ε ‖A‖ |x|) stopped early, anywhere up to ~400× above the
  // double solve's residual depending on the float rounding, hence on the build's SIMD width.
  // The best iterate is kept; false (b kept) if it stalls above round-off: the double factor
  // takes over.
  bool refine(VecX& b) const {
    const auto A = dense_.selfadjointView<Eigen::Lower>();
    refined_ = b;
    preconditionInPlace(refined_);
    double previous = std::numeric_limits<double>::infinity();
    for (int k = 0; k < kMaxRefinements; ++k) {
      residual_.noalias() = b - A * refined_;
      const double r = residual_.lpNorm<Eigen::Infinity>();
      if (!std::isfinite(r)) return false;
      if (r < previous) {
        best_ = refined_;
        best_residual_ = r;
      }
      if (r == 0.0 || !(r < 0.5 * previous)) break;  // converged: no longer halving
      previous = r;
      preconditionInPlace(residual_);
      refined_ += residual_;
    }
    const double scale = b.lpNorm<Eigen::Infinity>() + double(dense_.rows()) * largest_diagonal_ *
                                                           best_.lpNorm<Eigen::Infinity>();
    if (!(best_residual_ <= kRoundOffResidual * scale)) return false;
    b = best_;
    return true;
  }
  static constexpr int kMaxRefinements = 16;
  // A converged residual above this fraction of |b| + n ‖A‖ |x| is no double-accuracy solve.
  static constexpr double kRoundOffResidual = 1e-15;

  MatX dense_;
  double largest_diagonal_ = 0.0;
  mutable Eigen::LLT<MatX> llt_;
  Eigen::LLT<Eigen::MatrixXf> float_llt_;
  mutable bool single_ = false;  // the float factor is the one in use
  bool has_factor_ = false;
  mutable Eigen::MatrixXf float_factor_;  // the double L in single precision (empty: not made)
  mutable Eigen::VectorXf float_rhs_;
  mutable VecX refined_, residual_, best_;
  mutable double best_residual_ = 0.0;
};

/// Eigen's simplicial LLᵀ with the permuted copy P A Pᵀ kept between factorizations: Eigen's own
/// factorize() rebuilds it (with heap allocations) on every call, here only the values are
/// gathered through an index map computed once per pattern.
class PermutedSimplicialLLT
    : public Eigen::SimplicialLLT<SpMat, Eigen::Lower, Eigen::AMDOrdering<int>> {
 public:
  /// Ordering, elimination tree and value map for the pattern of A (compressed).
  void analyze(const SpMat& A) {
    analyzePattern(A);
    // Upper triangle of P A Pᵀ holds each lower entry of A once: its values, set to the index
    // of the source entry (exact in double), give the map.
    SpMat indices = A;
    for (Eigen::Index k = 0; k < indices.nonZeros(); ++k) indices.valuePtr()[k] = double(k);
    permuted_.resize(A.rows(), A.cols());
    permuted_.template selfadjointView<Eigen::Upper>() =
        indices.template selfadjointView<Eigen::Lower>().twistedBy(this->m_P);
    permuted_.makeCompressed();
    source_.resize(size_t(permuted_.nonZeros()));
    for (Eigen::Index k = 0; k < permuted_.nonZeros(); ++k)
      source_[size_t(k)] = int(permuted_.valuePtr()[k]);
  }
  /// Numeric factorization of A, whose pattern is the one given to analyze().
  void factorizeSamePattern(const SpMat& A) {
    const double* values = A.valuePtr();
    double* permuted = permuted_.valuePtr();
    for (size_t k = 0; k < source_.size(); ++k) permuted[k] = values[source_[k]];
    this->template factorize_preordered<false>(permuted_);
  }

 private:
  SpMat permuted_;           // upper triangle of P A Pᵀ, n × n
  std::vector<int> source_;  // value index in A of each stored entry of permuted_
};

/// Simplicial Cholesky L Lᵀ = P A Pᵀ (AMD ordering) of the lower triangle; the ordering and
/// elimination tree are kept while the pattern of A stays the same. (On the walking avatar's
/// 144-DoF Hessian AMD factors in ~36 µs, the natural order in ~81 µs, leaves-first ~41 µs.)
class SparseCholeskySolver final : public LinearSolver {
 public:
  bool factorize(const SpMat& A_in) override {
    detail::checkSquare(A_in, "SparseCholeskySolver::factorize");
    has_factor_ = false;
    const SpMat* A = &A_in;
    if (!A_in.isCompressed()) {
      compressed_ = A_in;
      compressed_.makeCompressed();
      A = &compressed_;
    }
    ++factorizations_;
    if (!detail::allFinite(*A)) return false;
    if (!analyzed_ || !samePattern(*A)) {
      llt_.analyze(*A);
      analyzed_ = true;
      ++analyses_;
      outer_.assign(A->outerIndexPtr(), A->outerIndexPtr() + A->outerSize() + 1);
      inner_.assign(A->innerIndexPtr(), A->innerIndexPtr() + A->nonZeros());
    }
    llt_.factorizeSamePattern(*A);
    if (llt_.info() != Eigen::Success) return false;
    // Same pivot floor as the dense solver: a nearly singular A gives no usable direction.
    const VecX pivots = llt_.matrixL().nestedExpression().diagonal();
    if (!(pivots.minCoeff() > std::sqrt(kRelativePivotFloor) * pivots.maxCoeff())) return false;
    n_ = A->rows();
    has_factor_ = true;
    return true;
  }

  VecX solve(const VecX& b) const override {
    if (!has_factor_)
      throw Error(
          "SparseCholeskySolver::solve: no factor (the last factorize() failed or was never "
          "called)");
    if (b.size() != n_)
      throw InputError("SparseCholeskySolver::solve: b must have " + std::to_string(n_) +
                       " entries, got " + std::to_string(b.size()));
    return llt_.solve(b);
  }

  bool hasFactor() const override { return has_factor_; }
  int factorRows() const override { return has_factor_ ? int(n_) : 0; }

  std::string name() const override { return "eigen-simplicial-llt"; }

 private:
  bool samePattern(const SpMat& A) const {
    return Eigen::Index(outer_.size()) == A.outerSize() + 1 &&
           Eigen::Index(inner_.size()) == A.nonZeros() &&
           std::equal(outer_.begin(), outer_.end(), A.outerIndexPtr()) &&
           std::equal(inner_.begin(), inner_.end(), A.innerIndexPtr());
  }

  PermutedSimplicialLLT llt_;
  SpMat compressed_;
  std::vector<int> outer_, inner_;
  Eigen::Index n_ = 0;
  bool analyzed_ = false;
  bool has_factor_ = false;
};

}  // namespace

std::unique_ptr<LinearSolver> makeLinearSolver(LinearSolverType type, int n, int dense_threshold) {
  switch (type) {
    case LinearSolverType::Dense:
      return std::make_unique<DenseCholeskySolver>();
    case LinearSolverType::Cholmod:
      return detail::makeCholmodSolver();
    case LinearSolverType::SparseLLT:
      return std::make_unique<SparseCholeskySolver>();
    case LinearSolverType::Auto:
      if (n < 0) throw InputError("makeLinearSolver: n must be ≥ 0, got " + std::to_string(n));
      if (n <= dense_threshold) return std::make_unique<DenseCholeskySolver>();
      return detail::makeCholmodSolver();
  }
  throw InputError("makeLinearSolver: unknown LinearSolverType " + std::to_string(int(type)));
}

}  // namespace flsh
