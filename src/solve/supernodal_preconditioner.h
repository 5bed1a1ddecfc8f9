// A single-precision copy of a CHOLMOD supernodal factor, for use as a preconditioner (not
// public API). PCG on a lagged factor spends its time in two triangular solves per iteration,
// and those are bound by reading the factor: float values halve the bytes read, and the
// elimination tree splits the solves into independent subtrees that run on separate threads.
//
// Layout (CHOLMOD's supernodal L, P A Pᵀ = L Lᵀ): supernode s holds columns
// [super[s], super[s+1]) as a dense column-major block of nrow(s) = pi[s+1] − pi[s] rows whose
// row indices are s_rows[pi[s] …] (the first ncol(s) of them are the supernode's own columns,
// in order), values from px[s].
#pragma once

#include <vector>

#include "flsh/core/types.h"

struct cholmod_factor_struct;

namespace flsh::detail {

class SupernodalPreconditioner {
 public:
  /// Copies the values of a numeric supernodal LLᵀ factor (is_super, is_ll, CHOLMOD_INT
  /// indices, real double values) into float and plans the split of the solves over `threads`
  /// threads (1: serial). The symbolic part (supernodes, rows, the plan) is kept while the
  /// factor's structure stays the same. Throws Error for any other kind of factor.
  void build(const cholmod_factor_struct& L, int threads);
  /// b ← (Pᵀ L Lᵀ P)⁻¹ b with the float factor (float arithmetic inside; relative difference
  /// from the double solve ~1e-7 × the condition of L). Throws Error without a build.
  void solveInPlace(VecX& b) const;
  bool built() const { return n_ > 0; }
  /// Threads the solves use (subtree groups; 1 when no split pays off) and the share of the factor's entries in the part
  /// solved by one thread (the top of the elimination tree, above the split).
  int threads() const { return int(thread_supernodes_.size()); }
  double serialShare() const { return serial_share_; }

 private:
  void plan(int threads);
  /// One supernode of L y = c (top_updates: where this thread collects the updates of the top
  /// part's rows; null when solving the top part itself) and of Lᵀ x = y; scratch holds the
  /// supernode's off-diagonal rows.
  void forward(int s, float* y, float* top_updates, float* scratch) const;
  void backward(int s, float* y, float* scratch) const;

  int n_ = 0, nsuper_ = 0, planned_threads_ = 0;
  std::vector<int> super_, pi_, px_, rows_, perm_;
  std::vector<float> values_;
  // The plan: supernodes above the split (increasing), each thread's supernodes (increasing),
  // and for every column its place among the top supernodes' columns (−1 below the split).
  std::vector<int> top_supernodes_;
  std::vector<std::vector<int>> thread_supernodes_;
  std::vector<int> top_index_;
  int top_columns_ = 0;
  double serial_share_ = 1.0;
  mutable std::vector<float> y_;
  mutable std::vector<std::vector<float>> top_updates_, scratch_;
};

}  // namespace flsh::detail
