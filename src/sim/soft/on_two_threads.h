// Runs two parts of an evaluation on a team of two OpenMP threads (the ROM's terms).
#pragma once

#include <omp.h>

#include "core/first_failure.h"
#include "flsh/core/types.h"

namespace flsh::detail {

/// Loops over nodes whose work is ~0.3–1 µs per node (a posedirs block, a skinned point of the
/// previous states) split in halves from this many nodes: waking the second thread costs a few
/// µs, each half saves ≥ 40.
constexpr size_t kSplitNodes = 128;

/// Runs part(0) and part(1) on a team of two OpenMP threads (both on the calling thread when
/// OpenMP is limited to one, by OMP_NUM_THREADS=1 or omp_set_num_threads(1), or in a nested
/// region); the first exception either throws is rethrown after both.
template <class Part>
void onTwoThreads(Part&& part) {
  FirstFailure failure;
  const int team = omp_get_max_threads() >= 2 ? 2 : 1;
#pragma omp parallel num_threads(team) if (team > 1)
  {
    const int threads = omp_get_num_threads(), t = omp_get_thread_num();
    for (int p = t; p < 2; p += threads) failure.run([&] { part(p); });
  }
  failure.rethrow();
}

/// out += a · b for a long inner dimension and a small result (e.g. 207 × 20 670 · 20 670 × 100):
/// each of two threads multiplies half of the inner dimension on its own, and the halves are
/// added in a fixed order. Eigen's threaded product splits the result instead and its threads
/// wait on each other spinning: on a loaded machine such products took ~0.5 s instead of ~10 ms
/// (the soft surface's cotangents of 100 steps, 2026-12-02).
template <class A, class B, class Out>
void addLongInnerProduct(const A& a, const B& b, Out&& out) {
  const Eigen::Index K = a.cols(), half = K / 2;
  MatX part[2];
  onTwoThreads([&](int p) {
    const Eigen::Index start = p == 0 ? 0 : half, size = p == 0 ? half : K - half;
    part[p].noalias() = a.middleCols(start, size) * b.middleRows(start, size);
  });
  out += part[0] + part[1];
}

}  // namespace flsh::detail
