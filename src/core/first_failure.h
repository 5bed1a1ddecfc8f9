// The first exception thrown inside an OpenMP region, kept to be rethrown after it (an
// exception must not leave a parallel region). Private to the library.
#pragma once

#include <exception>
#include <mutex>
#include <utility>

namespace flsh::detail {

class FirstFailure {
 public:
  /// Calls f(); an exception it throws is kept if it is the first one, not propagated.
  template <class F>
  void run(F&& f) noexcept {
    try {
      std::forward<F>(f)();
    } catch (...) {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!failure_) failure_ = std::current_exception();
    }
  }
  /// After the region: rethrows the kept exception, if any.
  void rethrow() const {
    if (failure_) std::rethrow_exception(failure_);
  }

 private:
  std::mutex mutex_;
  std::exception_ptr failure_;
};

}  // namespace flsh::detail
