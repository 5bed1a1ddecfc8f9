// CHOLMOD supernodal Cholesky behind the LinearSolver interface. The input matrix is wrapped,
// not copied: CHOLMOD reads Eigen's compressed column storage directly (stype = −1: only the
// lower triangle is used). The symbolic analysis (fill-reducing ordering, supernodes) is kept
// while the pattern stays the same, which is the common case across Newton iterations.
#include <cholmod.h>
#include <omp.h>

#include <algorithm>
#include <cstring>
#include <string>
#include <vector>

#include "flsh/core/error.h"
#include "solve/linear_solver_detail.h"
#include "solve/supernodal_preconditioner.h"

namespace flsh {

namespace {

using detail::PreconditionerSplit;

/// Runs CHOLMOD's own OpenMP loops on the calling thread while alive. Debian's CHOLMOD asks
/// for 4 threads (num_threads(CHOLMOD_OMP_NUM_THREADS), whatever OMP_NUM_THREADS says) in
/// loops that copy and clear each supernode's few hundred entries: a thread wake-up per
/// supernode. On the 2-core machine the FEM walk's 26 k-DoF factorization took 0.22–0.30 s
/// with them and 0.13–0.15 s without (1742 supernodes, 1.16 GFlop; docs/benchmarks.md). The
/// BLAS calls, where the flops are, keep OpenBLAS's own threads. The ICV is process-wide in
/// libgomp, so it is restored at once; factorizations run on the thread that drives Newton,
/// outside any parallel region of the library.
class SerialOpenMp {
 public:
  SerialOpenMp() : levels_(omp_get_max_active_levels()) { omp_set_max_active_levels(0); }
  ~SerialOpenMp() { omp_set_max_active_levels(levels_); }
  SerialOpenMp(const SerialOpenMp&) = delete;
  SerialOpenMp& operator=(const SerialOpenMp&) = delete;

 private:
  int levels_;
};

class CholmodSolver final : public LinearSolver {
 public:
  CholmodSolver() {
    cholmod_start(&common_);
    common_.supernodal = CHOLMOD_SUPERNODAL;
    // Ordering: CHOLMOD's default (nmethods = 0) is kept: AMD, plus METIS when AMD's fill is
    // high, the best one kept. On 25k-DoF tet-grid Hessians with 144 bone DoFs it chose METIS,
    // whose factors need 3.95 / 8.35 / 15.1 GFlop on 10×10×84 / 14×14×43 / 20×20×21 node grids
    // against AMD's 4.43 / 12.3 / 26.2; the extra analysis (~0.5 s) is paid once per pattern.
    // Threads: the supernodal kernels call BLAS, on Debian the openblas-pthread variant, which
    // uses every core unless OPENBLAS_NUM_THREADS says otherwise (a second thread does work
    // in the factorization); it is not set here, as the generic libblas.so.3 does not guarantee
    // openblas_set_num_threads.
    common_.print = 0;  // non-PD is an expected answer, not something to print
    common_.error_handler = nullptr;
  }

  ~CholmodSolver() override {
    if (factor_) cholmod_free_factor(&factor_, &common_);
    if (x_) cholmod_free_dense(&x_, &common_);
    if (y_) cholmod_free_dense(&y_, &common_);
    if (e_) cholmod_free_dense(&e_, &common_);
    cholmod_finish(&common_);
  }

  CholmodSolver(const CholmodSolver&) = delete;
  CholmodSolver& operator=(const CholmodSolver&) = delete;

  bool factorize(const SpMat& A_in) override {
    detail::checkSquare(A_in, "CholmodSolver::factorize");
    has_factor_ = false;
    preconditioner_current_ = false;
    const SpMat* A = &A_in;
    if (!A_in.isCompressed()) {  // CHOLMOD needs packed columns
      compressed_ = A_in;
      compressed_.makeCompressed();
      A = &compressed_;
    }
    ++factorizations_;
    if (!detail::allFinite(*A)) return false;

    cholmod_sparse view = wrap(*A);
    if (!factor_ || !samePattern(*A)) {
      if (factor_) cholmod_free_factor(&factor_, &common_);
      factor_ = cholmod_analyze(&view, &common_);
      if (!factor_ || common_.status < CHOLMOD_OK)
        throw Error("CholmodSolver::factorize: cholmod_analyze failed (status " +
                    std::to_string(common_.status) + ") on a " + std::to_string(A->rows()) + " × " +
                    std::to_string(A->cols()) + " matrix");
      ++analyses_;
      rememberPattern(*A);
    }
    int ok = 0;
    {
      SerialOpenMp serial;
      ok = cholmod_factorize(&view, factor_, &common_);
    }
    if (!ok || common_.status == CHOLMOD_NOT_POSDEF || factor_->minor < factor_->n) return false;
    if (common_.status < CHOLMOD_OK)
      throw Error("CholmodSolver::factorize: cholmod_factorize failed (status " +
                  std::to_string(common_.status) + ")");
    has_factor_ = true;
    return true;
  }

  VecX solve(const VecX& b) const override {
    solveIntoWorkspace(b, "CholmodSolver::solve");
    return Eigen::Map<const VecX>(static_cast<const double*>(x_->x), b.size());
  }

  void solveInPlace(VecX& b) const override {
    solveIntoWorkspace(b, "CholmodSolver::solveInPlace");
    b = Eigen::Map<const VecX>(static_cast<const double*>(x_->x), b.size());
  }

  void preconditionInPlace(VecX& b) const override {
    requireFactorFor(b, "CholmodSolver::preconditionInPlace");
    if (!factor_->is_super) {  // CHOLMOD chose a simplicial factor: no float copy
      solveInPlace(b);
      return;
    }
    if (!preconditioner_current_) {  // first use of this factor as a preconditioner
      preconditioner_.build(*factor_, omp_get_max_threads());
      preconditioner_current_ = true;
    }
    preconditioner_.solveInPlace(b);
  }

  PreconditionerSplit split() const {
    if (!preconditioner_current_) return {};
    return {preconditioner_.threads(), preconditioner_.serialShare()};
  }

  bool hasFactor() const override { return has_factor_; }
  int factorRows() const override { return has_factor_ ? int(factor_->n) : 0; }

  std::string name() const override { return "cholmod-supernodal"; }

 private:
  /// Throws Error without a factor and InputError unless b has its size; `who` names the caller.
  void requireFactorFor(const VecX& b, const char* who) const {
    if (!has_factor_)
      throw Error(std::string(who) +
                  ": no factor (the last factorize() failed or was never called)");
    if (b.size() != Eigen::Index(factor_->n))
      throw InputError(std::string(who) + ": b must have " + std::to_string(factor_->n) +
                       " entries, got " + std::to_string(b.size()));
  }

  /// x_ = A⁻¹ b with the held factor; `who` names the caller in errors.
  void solveIntoWorkspace(const VecX& b, const char* who) const {
    requireFactorFor(b, who);
    cholmod_dense rhs;
    std::memset(&rhs, 0, sizeof(rhs));
    rhs.nrow = rhs.d = rhs.nzmax = size_t(b.size());
    rhs.ncol = 1;
    rhs.x = const_cast<double*>(b.data());
    rhs.xtype = CHOLMOD_REAL;
    rhs.dtype = CHOLMOD_DOUBLE;
    // cholmod_solve2 keeps its result and workspaces (x_, y_, e_) between calls.
    if (!cholmod_solve2(CHOLMOD_A, factor_, &rhs, nullptr, &x_, nullptr, &y_, &e_, &common_))
      throw Error(std::string(who) + ": cholmod_solve2 failed (status " +
                  std::to_string(common_.status) + ")");
  }

  static cholmod_sparse wrap(const SpMat& A) {
    cholmod_sparse s;
    std::memset(&s, 0, sizeof(s));
    s.nrow = size_t(A.rows());
    s.ncol = size_t(A.cols());
    s.nzmax = size_t(A.nonZeros());
    s.p = const_cast<int*>(A.outerIndexPtr());
    s.i = const_cast<int*>(A.innerIndexPtr());
    s.x = const_cast<double*>(A.valuePtr());
    s.stype = -1;  // symmetric, lower triangle used, upper ignored
    s.itype = CHOLMOD_INT;
    s.xtype = CHOLMOD_REAL;
    s.dtype = CHOLMOD_DOUBLE;
    s.sorted = 1;  // Eigen keeps inner indices sorted in compressed mode
    s.packed = 1;
    return s;
  }

  bool samePattern(const SpMat& A) const {
    if (A.rows() != rows_ || A.nonZeros() != Eigen::Index(inner_.size())) return false;
    return std::equal(outer_.begin(), outer_.end(), A.outerIndexPtr()) &&
           std::equal(inner_.begin(), inner_.end(), A.innerIndexPtr());
  }

  void rememberPattern(const SpMat& A) {
    rows_ = A.rows();
    outer_.assign(A.outerIndexPtr(), A.outerIndexPtr() + A.outerSize() + 1);
    inner_.assign(A.innerIndexPtr(), A.innerIndexPtr() + A.nonZeros());
  }

  mutable cholmod_common common_;
  cholmod_factor* factor_ = nullptr;
  mutable cholmod_dense *x_ = nullptr, *y_ = nullptr, *e_ = nullptr;
  SpMat compressed_;
  Eigen::Index rows_ = -1;
  std::vector<int> outer_, inner_;
  bool has_factor_ = false;
  // The single-precision copy of factor_ (built on the first preconditionInPlace after each
  // factorization, so that exact solves alone never pay for it).
  mutable detail::SupernodalPreconditioner preconditioner_;
  mutable bool preconditioner_current_ = false;
};

}  // namespace

namespace detail {
std::unique_ptr<LinearSolver> makeCholmodSolver() { return std::make_unique<CholmodSolver>(); }

PreconditionerSplit preconditionerSplit(const LinearSolver& solver) {
  const auto* cholmod = dynamic_cast<const CholmodSolver*>(&solver);
  return cholmod ? cholmod->split() : PreconditionerSplit{};
}
}  // namespace detail

}  // namespace flsh
