#include <gtest/gtest.h>

#include <thread>

#include "depthfuse/daemon/bounded_queue.hpp"
#include "depthfuse/daemon/rate_meter.hpp"

namespace depthfuse::daemon {
namespace {

TEST(BoundedQueue, DropsTheOldestWhenFull) {
  BoundedQueue<int> q(3);
  for (int i = 0; i < 10; ++i) q.push(i);
  EXPECT_EQ(q.size(), 3u);
  EXPECT_EQ(q.dropped(), 7);
  EXPECT_EQ(*q.pop(std::chrono::milliseconds(0)), 7);
  EXPECT_EQ(*q.pop(std::chrono::milliseconds(0)), 8);
  EXPECT_EQ(*q.pop(std::chrono::milliseconds(0)), 9);
  EXPECT_FALSE(q.pop(std::chrono::milliseconds(1)).has_value());
}

TEST(BoundedQueue, CapacityOfAtLeastOneAndWake) {
  BoundedQueue<int> q(0);
  EXPECT_EQ(q.capacity(), 1u);
  EXPECT_FALSE(q.push(1));
  EXPECT_TRUE(q.push(2));
  EXPECT_EQ(*q.pop(std::chrono::milliseconds(0)), 2);
  std::thread waker([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    q.wake();
  });
  // Woken without an item: returns empty long before the (generous) timeout.
  EXPECT_FALSE(q.pop(std::chrono::seconds(30)).has_value());
  waker.join();
}

TEST(BoundedQueue, ProducerNeverWaitsForASlowConsumer) {
  BoundedQueue<int> q(2);
  std::atomic<int> consumed{0};
  std::atomic<bool> done{false};
  std::thread consumer([&] {
    while (!done) {
      if (q.pop(std::chrono::milliseconds(5))) {
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
        ++consumed;
      }
    }
  });
  for (int i = 0; i < 2000; ++i) q.push(i);
  done = true;
  consumer.join();
  EXPECT_EQ(consumed.load() + q.dropped() + static_cast<int64_t>(q.size()), 2000);
  EXPECT_GT(q.dropped(), 0);
}

TEST(RateMeter, MeasuresEventsPerSecond) {
  RateMeter m(2.0);
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < 40; ++i) m.add(t0 + std::chrono::milliseconds(50 * i));  // 20 Hz for 2 s
  EXPECT_NEAR(m.rate_hz(t0 + std::chrono::milliseconds(1950)), 20.0, 1.0);
  EXPECT_EQ(m.rate_hz(t0 + std::chrono::seconds(10)), 0.0);  // nothing in the window
}

}  // namespace
}  // namespace depthfuse::daemon
