// run_pair: both halves run, the second on another thread, however the callers overlap.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <thread>
#include <vector>

#include "parallel.hpp"

namespace depthfuse {
namespace {

TEST(Parallel, BothHalvesRunAndTheSecondOnAnotherThread) {
  for (int call = 0; call < 1000; ++call) {  // the kept thread, reused call after call
    std::thread::id first_id, second_id;
    run_pair(
        2, [&] { first_id = std::this_thread::get_id(); },
        [&] { second_id = std::this_thread::get_id(); });
    ASSERT_EQ(first_id, std::this_thread::get_id());
    ASSERT_NE(second_id, std::thread::id{});
    ASSERT_NE(second_id, first_id);
  }
}

TEST(Parallel, OneThreadRunsBothHalvesInOrderHere) {
  std::vector<int> order;
  std::thread::id second_id;
  run_pair(
      1, [&] { order.push_back(1); },
      [&] {
        order.push_back(2);
        second_id = std::this_thread::get_id();
      });
  EXPECT_EQ(order, (std::vector<int>{1, 2}));
  EXPECT_EQ(second_id, std::this_thread::get_id());
}

TEST(Parallel, NestedAndConcurrentCallsEachGetTheirSecondThread) {
  // A pass that itself splits (nested), called from two threads at once: the kept thread serves
  // one caller, the others get a thread of their own; none waits for another's half.
  std::atomic<int> runs{0};
  auto nested = [&] {
    for (int i = 0; i < 200; ++i)
      run_pair(
          2, [&] { run_pair(2, [&] { ++runs; }, [&] { ++runs; }); },
          [&] { run_pair(2, [&] { ++runs; }, [&] { ++runs; }); });
  };
  std::thread a(nested), b(nested);
  a.join();
  b.join();
  EXPECT_EQ(runs.load(), 2 * 200 * 4);
}

TEST(Parallel, AForkedChildSplitsWithoutTheParentsThread) {
  run_pair(2, [] {}, [] {});  // the parent's kept thread exists
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    ::alarm(10);  // a child waiting for a thread it does not have dies of SIGALRM instead
    std::atomic<int> runs{0};
    for (int i = 0; i < 10; ++i) run_pair(2, [&] { ++runs; }, [&] { ++runs; });
    ::_exit(runs.load() == 20 ? 0 : 1);
  }
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status)) << "the child hung or crashed";
  EXPECT_EQ(WEXITSTATUS(status), 0);
}

TEST(Parallel, HalvesCoverTheRangeOnce) {
  for (int count : {0, 1, 2, 7, 480}) {
    std::vector<int> seen(static_cast<size_t>(count), 0);
    run_halves(2, count, [&](int begin, int end) {
      for (int i = begin; i < end; ++i) ++seen[static_cast<size_t>(i)];
    });
    for (int s : seen) EXPECT_EQ(s, 1) << "count " << count;
  }
}

}  // namespace
}  // namespace depthfuse
