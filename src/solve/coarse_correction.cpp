#include "solve/coarse_correction.h"

#include <omp.h>

#include <algorithm>

namespace flsh::detail {

bool CoarseCorrection::build(const SpMat& H, const std::vector<int>& dofs) {
  active_ = false;
  H_ = nullptr;
  const int m = int(dofs.size());
  if (m == 0 || !H.isCompressed()) return false;
  dofs_ = dofs;
  // Place of each DoF in the coarse block (−1: not coarse).
  std::vector<int> place(size_t(H.rows()), -1);
  for (int k = 0; k < m; ++k) place[size_t(dofs[size_t(k)])] = k;
  MatX E = MatX::Zero(m, m);
  for (int k = 0; k < m; ++k)
    for (SpMat::InnerIterator it(H, dofs[size_t(k)]); it; ++it) {
      const int p = place[size_t(it.row())];
      if (p >= 0) E(p, k) = it.value();
    }
  // Two threads when the coarse columns hold enough entries to pay for waking the second.
  long entries = 0;
  for (int k = 0; k < m; ++k)
    entries += H.outerIndexPtr()[dofs[size_t(k)] + 1] - H.outerIndexPtr()[dofs[size_t(k)]];
  parallel_ = entries > 50000;
  E_.compute(E);
  if (E_.info() != Eigen::Success) return false;
  H_ = &H;
  active_ = true;
  return true;
}

void CoarseCorrection::coarseSolve(const VecX& r, VecX& t) const {
  t.resize(Eigen::Index(dofs_.size()));
  for (size_t k = 0; k < dofs_.size(); ++k) t[Eigen::Index(k)] = r[dofs_[k]];
  E_.solveInPlace(t);
}

void CoarseCorrection::subtractColumns(const VecX& t, VecX& v) const {
  const int* outer = H_->outerIndexPtr();
  const int* inner = H_->innerIndexPtr();
  const double* values = H_->valuePtr();
  const int n = int(H_->rows());
  // Each thread takes a range of rows of every column (rows sorted within a column): no shared
  // writes, and every entry of v gets its terms in the columns' order, as on one thread.
#pragma omp parallel if (parallel_)
  {
    const int parts = omp_get_num_threads(), p = omp_get_thread_num();
    const int r0 = int(long(p) * n / parts), r1 = int(long(p + 1) * n / parts);
    for (size_t k = 0; k < dofs_.size(); ++k) {
      const double tk = t[Eigen::Index(k)];
      if (tk == 0.0) continue;
      const int* begin = inner + outer[dofs_[k]];
      const int* end = inner + outer[dofs_[k] + 1];
      const int* first = parts == 1 ? begin : std::lower_bound(begin, end, r0);
      const int* last = parts == 1 ? end : std::lower_bound(first, end, r1);
      for (const int* it = first; it != last; ++it) v[*it] -= values[it - inner] * tk;
    }
  }
}

void CoarseCorrection::coarseResidual(const VecX& r, const VecX& y, VecX& s) const {
  // Row c of H y is column c · y (H symmetric).
  const int* outer = H_->outerIndexPtr();
  const int* inner = H_->innerIndexPtr();
  const double* values = H_->valuePtr();
  s.resize(Eigen::Index(dofs_.size()));
  const int m = int(dofs_.size());
#pragma omp parallel for schedule(static) if (parallel_)
  for (int k = 0; k < m; ++k) {
    double dot = 0.0;
    for (int i = outer[dofs_[k]]; i < outer[dofs_[k] + 1]; ++i) dot += values[i] * y[inner[i]];
    s[Eigen::Index(k)] = r[dofs_[k]] - dot;
  }
}

void CoarseCorrection::addCoarse(const VecX& s, VecX& v) const {
  t_ = s;
  E_.solveInPlace(t_);
  for (size_t k = 0; k < dofs_.size(); ++k) v[dofs_[k]] += t_[Eigen::Index(k)];
}

}  // namespace flsh::detail
