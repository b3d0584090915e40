// A sliding-window rate (see rate_meter.hpp): its events are under its own mutex, so add() and
// rate_hz() may come from different threads.
#include "depthfuse/daemon/rate_meter.hpp"

namespace depthfuse::daemon {

void RateMeter::add(std::chrono::steady_clock::time_point t) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!have_first_) {
    have_first_ = true;
    first_ = t;
  }
  events_.push_back(t);
  trim(t);
}

void RateMeter::trim(std::chrono::steady_clock::time_point now) const {
  const auto horizon = now - std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                 std::chrono::duration<double>(window_s_));
  while (!events_.empty() && events_.front() < horizon) events_.pop_front();
}

double RateMeter::rate_hz(std::chrono::steady_clock::time_point now) const {
  std::lock_guard<std::mutex> lock(mutex_);
  trim(now);
  if (!have_first_ || events_.empty()) return 0.0;
  // Young meters divide by their age, not the whole window, so the rate is right from the start.
  const double age_s = std::chrono::duration<double>(now - first_).count();
  const double span_s = std::min(window_s_, std::max(age_s, 1e-3));
  return static_cast<double>(events_.size()) / span_s;
}

void RateMeter::reset() {
  std::lock_guard<std::mutex> lock(mutex_);
  events_.clear();
  have_first_ = false;
}

}  // namespace depthfuse::daemon
