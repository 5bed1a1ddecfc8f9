// Runs two parts of an evaluation on a team of two OpenMP threads (the ROM's terms).
#pragma once

#include <omp.h>

#include "core/first_failure.h"

namespace flsh::detail {

/// Runs part(0) and part(1) on a team of two OpenMP threads (both on one thread when the team
/// has one, e.g. in a nested region); the first exception either throws is rethrown after both.
template <class Part>
void onTwoThreads(Part&& part) {
  FirstFailure failure;
#pragma omp parallel num_threads(2)
  {
    const int threads = omp_get_num_threads(), t = omp_get_thread_num();
    for (int p = t; p < 2; p += threads) failure.run([&] { part(p); });
  }
  failure.rethrow();
}

}  // namespace flsh::detail
