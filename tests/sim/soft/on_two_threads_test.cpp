// The ROM's two-part parallel loops: both parts run once, on two threads when OpenMP allows two
// and on the calling thread alone when it is limited to one (OMP_NUM_THREADS=1, as when many
// processes share a machine), and a part's exception reaches the caller.
#include "sim/soft/on_two_threads.h"

#include <gtest/gtest.h>
#include <omp.h>

#include <atomic>
#include <stdexcept>
#include <thread>

namespace flsh {
namespace {

// Restores OpenMP's thread count when a test ends.
class ThreadLimit {
 public:
  explicit ThreadLimit(int threads) : saved_(omp_get_max_threads()) {
    omp_set_num_threads(threads);
  }
  ~ThreadLimit() { omp_set_num_threads(saved_); }

 private:
  int saved_;
};

struct PartRuns {
  std::atomic<int> count[2] = {0, 0};
  std::thread::id thread[2];
};

// Runs both parts with OpenMP limited to `threads`; each part runs exactly once.
void runParts(int threads, PartRuns& runs) {
  ThreadLimit limit(threads);
  detail::onTwoThreads([&](int p) {
    runs.count[p]++;
    runs.thread[p] = std::this_thread::get_id();
  });
  EXPECT_EQ(runs.count[0], 1);
  EXPECT_EQ(runs.count[1], 1);
}

TEST(OnTwoThreads, OneThreadWhenOpenMPIsLimitedToOne) {
  PartRuns runs;
  runParts(1, runs);
  EXPECT_EQ(runs.thread[0], std::this_thread::get_id());
  EXPECT_EQ(runs.thread[1], std::this_thread::get_id());
}

TEST(OnTwoThreads, TwoThreadsWhenOpenMPAllowsThem) {
  PartRuns runs;
  runParts(2, runs);
  EXPECT_NE(runs.thread[0], runs.thread[1]);
}

TEST(OnTwoThreads, APartsExceptionReachesTheCaller) {
  for (int threads : {1, 2}) {
    ThreadLimit limit(threads);
    std::atomic<int> finished{0};
    const auto part = [&](int p) {
      if (p == 1) throw std::runtime_error("part 1 failed");
      ++finished;
    };
    EXPECT_THROW(detail::onTwoThreads(part), std::runtime_error) << threads << " threads";
    EXPECT_EQ(finished, 1) << threads << " threads";
  }
}

// The halves of the inner dimension add up to the whole product, one thread or two.
TEST(OnTwoThreads, LongInnerProductMatchesTheWholeProduct) {
  const MatX a = MatX::Random(7, 301), b = MatX::Random(301, 5);
  const MatX expected = MatX::Constant(7, 5, 1.0) + a * b;
  for (int threads : {1, 2}) {
    ThreadLimit limit(threads);
    MatX out = MatX::Constant(7, 5, 1.0);
    detail::addLongInnerProduct(a, b, out);
    EXPECT_LT((out - expected).norm(), 1e-12 * expected.norm()) << threads << " threads";
  }
}

}  // namespace
}  // namespace flsh
