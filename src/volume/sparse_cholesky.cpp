#include "volume/sparse_cholesky.h"

#include <cholmod.h>

#include <algorithm>
#include <cstring>
#include <mutex>

#include "flsh/core/error.h"

namespace flsh::detail {

namespace {
// Columns solved together: wide enough for CHOLMOD's blocked (BLAS-3) triangular solves, narrow
// enough to bound the dense work arrays (rows × 256 doubles).
constexpr Eigen::Index kSolveBlockColumns = 256;
}  // namespace

struct SparseCholesky::Impl {
  mutable std::mutex mutex;  // cholmod_common is scratch space: one solve at a time
  mutable cholmod_common common;
  cholmod_factor* factor = nullptr;

  Impl() {
    cholmod_start(&common);
    common.supernodal = CHOLMOD_SUPERNODAL;
    common.print = 0;
    common.error_handler = nullptr;
  }
  ~Impl() {
    if (factor) cholmod_free_factor(&factor, &common);
    cholmod_finish(&common);
  }
};

SparseCholesky::SparseCholesky(const SpMat& A, const std::string& who)
    : impl_(std::make_unique<Impl>()), rows_(int(A.rows())), who_(who) {
  if (A.rows() != A.cols())
    throw InputError(who + ": the matrix to factor is " + std::to_string(A.rows()) + " × " +
                     std::to_string(A.cols()) + ", expected square");
  SpMat lower = A.triangularView<Eigen::Lower>();
  lower.makeCompressed();
  cholmod_sparse view;
  std::memset(&view, 0, sizeof(view));
  view.nrow = view.ncol = size_t(A.rows());
  view.nzmax = size_t(lower.nonZeros());
  view.p = lower.outerIndexPtr();
  view.i = lower.innerIndexPtr();
  view.x = lower.valuePtr();
  view.stype = -1;  // symmetric: lower triangle used
  view.itype = CHOLMOD_INT;
  view.xtype = CHOLMOD_REAL;
  view.dtype = CHOLMOD_DOUBLE;
  view.sorted = 1;
  view.packed = 1;
  Impl& f = *impl_;
  f.factor = cholmod_analyze(&view, &f.common);
  if (!f.factor || f.common.status < CHOLMOD_OK)
    throw Error(who + ": cholmod_analyze failed (status " + std::to_string(f.common.status) +
                ") on " + std::to_string(rows_) + " unknowns");
  const int ok = cholmod_factorize(&view, f.factor, &f.common);
  if (!ok || f.common.status != CHOLMOD_OK || f.factor->minor < f.factor->n)
    throw Error(who + ": the " + std::to_string(rows_) + " × " + std::to_string(rows_) +
                " matrix is not positive definite (CHOLMOD status " +
                std::to_string(f.common.status) + ", column " + std::to_string(f.factor->minor) +
                ")");
}

SparseCholesky::~SparseCholesky() = default;

MatX SparseCholesky::solve(const MatX& B) const {
  if (B.rows() != rows_)
    throw InputError(who_ + ": a right-hand side has " + std::to_string(B.rows()) +
                     " rows, expected " + std::to_string(rows_));
  MatX X(B.rows(), B.cols());
  if (rows_ == 0 || B.cols() == 0) return X;
  const Impl& f = *impl_;
  std::lock_guard<std::mutex> lock(f.mutex);
  for (Eigen::Index begin = 0; begin < B.cols(); begin += kSolveBlockColumns) {
    const Eigen::Index width = std::min<Eigen::Index>(kSolveBlockColumns, B.cols() - begin);
    MatX rhs = B.middleCols(begin, width);
    cholmod_dense b;
    std::memset(&b, 0, sizeof(b));
    b.nrow = b.d = size_t(rows_);
    b.ncol = size_t(width);
    b.nzmax = size_t(rhs.size());
    b.x = rhs.data();
    b.xtype = CHOLMOD_REAL;
    b.dtype = CHOLMOD_DOUBLE;
    cholmod_dense* x = cholmod_solve(CHOLMOD_A, f.factor, &b, &f.common);
    if (!x)
      throw Error(who_ + ": cholmod_solve failed (status " + std::to_string(f.common.status) + ")");
    X.middleCols(begin, width) =
        Eigen::Map<const MatX>(static_cast<const double*>(x->x), rows_, width);
    cholmod_free_dense(&x, &f.common);
  }
  return X;
}

}  // namespace flsh::detail
