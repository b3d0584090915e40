// Events per second over a sliding window (the last few seconds), for heartbeat rates.
// Thread-safe: add() from a receive or worker thread, rate_hz() from the heartbeat.
#pragma once

#include <chrono>
#include <algorithm>
#include <deque>
#include <mutex>

namespace depthfuse::daemon {

class RateMeter {
 public:
  explicit RateMeter(double window_s = 3.0) : window_s_(window_s) {}
  void add(std::chrono::steady_clock::time_point t = std::chrono::steady_clock::now());
  double rate_hz(std::chrono::steady_clock::time_point now = std::chrono::steady_clock::now()) const;
  void reset();

 private:
  void trim(std::chrono::steady_clock::time_point now) const;
  double window_s_;
  mutable std::mutex mutex_;
  mutable std::deque<std::chrono::steady_clock::time_point> events_;
  std::chrono::steady_clock::time_point first_{};
  bool have_first_ = false;
};

}  // namespace depthfuse::daemon
