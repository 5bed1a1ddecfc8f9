// Single-precision supernodal triangular solves on a copy of a CHOLMOD factor, split over
// threads along the elimination tree (see supernodal_preconditioner.h).
//
// The split: the supernodal elimination tree is cut into a top part (the root and the heaviest
// supernodes below it, solved by one thread) and disjoint subtrees, dealt to the threads so
// that their numbers of factor entries balance. In the forward solve L y = c a subtree only
// updates its own rows and the top part's rows (its ancestors): each thread collects the
// latter in its own buffer, summed before the top part is solved. The backward solve Lᵀ x = y
// runs the top part first; the subtrees then only read the top part's values.
#include "solve/supernodal_preconditioner.h"

#include <cholmod.h>
#include <omp.h>

#include <algorithm>
#include <numeric>
#include <string>

#include "flsh/core/error.h"

namespace flsh::detail {

namespace {

using VecF = Eigen::Matrix<float, Eigen::Dynamic, 1>;
using MatF = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic>;

}  // namespace

void SupernodalPreconditioner::build(const cholmod_factor& L, int threads) {
  if (!L.is_super || !L.is_ll || L.itype != CHOLMOD_INT || L.xtype != CHOLMOD_REAL ||
      L.dtype != CHOLMOD_DOUBLE || !L.x)
    throw Error("SupernodalPreconditioner::build: needs a numeric supernodal LLᵀ factor with "
                "int indices and double values (got is_super " + std::to_string(L.is_super) +
                ", is_ll " + std::to_string(L.is_ll) + ", itype " + std::to_string(L.itype) +
                ", xtype " + std::to_string(L.xtype) + ")");
  const int n = int(L.n), nsuper = int(L.nsuper);
  const int* super = static_cast<const int*>(L.super);
  const int* pi = static_cast<const int*>(L.pi);
  const int* px = static_cast<const int*>(L.px);
  const int* perm = static_cast<const int*>(L.Perm);
  threads = std::max(1, threads);
  const bool same = n == n_ && nsuper == nsuper_ && threads == planned_threads_ &&
                    std::equal(super_.begin(), super_.end(), super) &&
                    std::equal(pi_.begin(), pi_.end(), pi) && std::equal(px_.begin(), px_.end(), px) &&
                    std::equal(perm_.begin(), perm_.end(), perm) &&
                    std::equal(rows_.begin(), rows_.end(), static_cast<const int*>(L.s));
  if (!same) {
    n_ = n;
    nsuper_ = nsuper;
    super_.assign(super, super + nsuper + 1);
    pi_.assign(pi, pi + nsuper + 1);
    px_.assign(px, px + nsuper + 1);
    rows_.assign(static_cast<const int*>(L.s), static_cast<const int*>(L.s) + pi[nsuper]);
    perm_.assign(perm, perm + n);
    planned_threads_ = threads;
    plan(threads);
  }
  const double* x = static_cast<const double*>(L.x);
  const long long count = px[nsuper];
  values_.resize(size_t(count));
#pragma omp parallel for schedule(static) if (count > 200000)
  for (long long k = 0; k < count; ++k) values_[size_t(k)] = float(x[k]);
  y_.resize(size_t(n));
}

void SupernodalPreconditioner::plan(int threads) {
  const int S = nsuper_;
  std::vector<int> column_super(static_cast<size_t>(n_));
  for (int s = 0; s < S; ++s)
    for (int c = super_[s]; c < super_[s + 1]; ++c) column_super[size_t(c)] = s;
  // Parent of a supernode: the one holding its smallest off-diagonal row. CHOLMOD numbers
  // supernodes in a topological order (children first); anything else keeps the solve serial.
  std::vector<int> parent(static_cast<size_t>(S), -1);
  std::vector<double> work(static_cast<size_t>(S)), subtree(static_cast<size_t>(S));
  bool topological = true;
  size_t largest_off_diagonal = 0;
  for (int s = 0; s < S; ++s) {
    const int nc = super_[s + 1] - super_[s], nr = pi_[s + 1] - pi_[s];
    largest_off_diagonal = std::max(largest_off_diagonal, size_t(nr - nc));
    work[size_t(s)] = double(nr) * nc + nr;  // entries read, plus the rows scattered or gathered
    if (nr > nc) {
      const int* r = rows_.data() + pi_[s] + nc;
      parent[size_t(s)] = column_super[size_t(*std::min_element(r, r + (nr - nc)))];
      if (parent[size_t(s)] <= s) topological = false;
    }
  }
  for (int s = 0; s < S; ++s) {
    subtree[size_t(s)] += work[size_t(s)];
    if (parent[size_t(s)] > s) subtree[size_t(parent[size_t(s)])] += subtree[size_t(s)];
  }
  const double total = std::accumulate(work.begin(), work.end(), 0.0);
  std::vector<std::vector<int>> children(static_cast<size_t>(S));
  std::vector<int> candidates;  // subtree roots below the top part
  for (int s = 0; s < S; ++s) {
    if (parent[size_t(s)] >= 0)
      children[size_t(parent[size_t(s)])].push_back(s);
    else
      candidates.push_back(s);
  }
  std::vector<char> in_top(static_cast<size_t>(S), 0);
  std::vector<int> bin_of(static_cast<size_t>(S), 0);  // per subtree root: its thread
  if (threads > 1 && topological) {
    // Greedy: deal the candidate subtrees to the threads heaviest first (each to the lightest
    // thread); while that is unbalanced, move the heaviest candidate into the top part and make
    // its children candidates. Keep the cut with the least estimated time (top + heaviest
    // thread); stop once the top part alone would cost more than that.
    double top_work = 0.0, best_time = total;
    std::vector<int> best_top, best_candidates;
    std::vector<double> load(static_cast<size_t>(threads));
    auto deal = [&](std::vector<int>& cand, std::vector<int>* bins) {
      std::sort(cand.begin(), cand.end(),
                [&](int a, int b) { return subtree[size_t(a)] > subtree[size_t(b)]; });
      std::fill(load.begin(), load.end(), 0.0);
      for (int c : cand) {
        const size_t t = size_t(std::min_element(load.begin(), load.end()) - load.begin());
        load[t] += subtree[size_t(c)];
        if (bins) (*bins)[size_t(c)] = int(t);
      }
      return *std::max_element(load.begin(), load.end());
    };
    std::vector<int> top;
    for (int round = 0; round < S && !candidates.empty(); ++round) {
      const double time = top_work + deal(candidates, nullptr);
      if (time < best_time) {
        best_time = time;
        best_top = top;
        best_candidates = candidates;
      }
      if (top_work >= best_time) break;
      const int heaviest = candidates.front();  // sorted by deal()
      candidates.erase(candidates.begin());
      top.push_back(heaviest);
      top_work += work[size_t(heaviest)];
      candidates.insert(candidates.end(), children[size_t(heaviest)].begin(),
                        children[size_t(heaviest)].end());
    }
    if (best_time < total) {
      for (int s : best_top) in_top[size_t(s)] = 1;
      candidates = best_candidates;
      deal(candidates, &bin_of);
    } else {
      threads = 1;
    }
  } else {
    threads = 1;
  }
  // Owner of every supernode (−1: the top part), parents before children.
  std::vector<int> owner(static_cast<size_t>(S), 0);
  for (int s = S - 1; s >= 0; --s) {
    const int p = parent[size_t(s)];
    if (threads == 1) owner[size_t(s)] = 0;
    else if (in_top[size_t(s)]) owner[size_t(s)] = -1;
    else if (p < 0 || in_top[size_t(p)]) owner[size_t(s)] = bin_of[size_t(s)];
    else owner[size_t(s)] = owner[size_t(p)];
  }
  top_supernodes_.clear();
  thread_supernodes_.assign(size_t(threads), {});
  top_index_.assign(size_t(n_), -1);
  top_columns_ = 0;
  double top_work = 0.0;
  for (int s = 0; s < S; ++s) {
    if (owner[size_t(s)] >= 0) {
      thread_supernodes_[size_t(owner[size_t(s)])].push_back(s);
      continue;
    }
    top_supernodes_.push_back(s);
    top_work += work[size_t(s)];
    for (int c = super_[s]; c < super_[s + 1]; ++c) top_index_[size_t(c)] = top_columns_++;
  }
  serial_share_ = threads == 1 ? 1.0 : top_work / std::max(total, 1.0);
  top_updates_.assign(size_t(threads), std::vector<float>(size_t(top_columns_)));
  scratch_.assign(size_t(threads), std::vector<float>(largest_off_diagonal));
}

void SupernodalPreconditioner::forward(int s, float* y, float* top_updates,
                                       float* scratch) const {
  const int j0 = super_[s], nc = super_[s + 1] - j0, nr = pi_[s + 1] - pi_[s], m = nr - nc;
  const Eigen::Map<const MatF> B(values_.data() + px_[s], nr, nc);
  Eigen::Map<VecF> yd(y + j0, nc);
  B.topRows(nc).triangularView<Eigen::Lower>().solveInPlace(yd);
  if (m == 0) return;
  Eigen::Map<VecF> product(scratch, m);
  product.noalias() = B.bottomRows(m) * yd;
  const int* rows = rows_.data() + pi_[s] + nc;
  for (int i = 0; i < m; ++i) {
    const int r = rows[i];
    const int t = top_updates ? top_index_[size_t(r)] : -1;
    if (t >= 0)
      top_updates[t] += product[i];
    else
      y[r] -= product[i];
  }
}

void SupernodalPreconditioner::backward(int s, float* y, float* scratch) const {
  const int j0 = super_[s], nc = super_[s + 1] - j0, nr = pi_[s + 1] - pi_[s], m = nr - nc;
  const Eigen::Map<const MatF> B(values_.data() + px_[s], nr, nc);
  Eigen::Map<VecF> yd(y + j0, nc);
  if (m > 0) {
    Eigen::Map<VecF> gathered(scratch, m);
    const int* rows = rows_.data() + pi_[s] + nc;
    for (int i = 0; i < m; ++i) gathered[i] = y[rows[i]];
    yd.noalias() -= B.bottomRows(m).transpose() * gathered;
  }
  B.topRows(nc).transpose().triangularView<Eigen::Upper>().solveInPlace(yd);
}

void SupernodalPreconditioner::solveInPlace(VecX& b) const {
  if (n_ == 0) throw Error("SupernodalPreconditioner::solveInPlace: no factor (build first)");
  if (b.size() != n_)
    throw InputError("SupernodalPreconditioner::solveInPlace: b must have " + std::to_string(n_) +
                     " entries, got " + std::to_string(b.size()));
  float* y = y_.data();
  for (int k = 0; k < n_; ++k) y[k] = float(b[perm_[size_t(k)]]);
  const int groups = int(thread_supernodes_.size());
  if (groups == 1) {
    float* scratch = scratch_[0].data();
    const std::vector<int>& all = thread_supernodes_[0];
    for (int s : all) forward(s, y, nullptr, scratch);
    for (auto it = all.rbegin(); it != all.rend(); ++it) backward(*it, y, scratch);
  } else {
#pragma omp parallel for schedule(static, 1) num_threads(groups)
    for (int t = 0; t < groups; ++t) {
      std::vector<float>& updates = top_updates_[size_t(t)];
      std::fill(updates.begin(), updates.end(), 0.0f);
      for (int s : thread_supernodes_[size_t(t)])
        forward(s, y, updates.data(), scratch_[size_t(t)].data());
    }
    for (int s : top_supernodes_)
      for (int c = super_[s]; c < super_[s + 1]; ++c) {
        const size_t index = size_t(top_index_[size_t(c)]);
        float sum = 0.0f;
        for (int t = 0; t < groups; ++t) sum += top_updates_[size_t(t)][index];
        y[c] -= sum;
      }
    float* scratch = scratch_[0].data();
    for (int s : top_supernodes_) forward(s, y, nullptr, scratch);
    for (auto it = top_supernodes_.rbegin(); it != top_supernodes_.rend(); ++it)
      backward(*it, y, scratch);
#pragma omp parallel for schedule(static, 1) num_threads(groups)
    for (int t = 0; t < groups; ++t) {
      const std::vector<int>& mine = thread_supernodes_[size_t(t)];
      for (auto it = mine.rbegin(); it != mine.rend(); ++it)
        backward(*it, y, scratch_[size_t(t)].data());
    }
  }
  for (int k = 0; k < n_; ++k) b[perm_[size_t(k)]] = double(y[k]);
}

}  // namespace flsh::detail
