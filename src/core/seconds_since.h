// Wall-clock seconds since a steady_clock time point: the timings the build reports and the
// progress lines print. Private to src/.
#pragma once

#include <chrono>

namespace flsh::detail {

inline double secondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace flsh::detail
