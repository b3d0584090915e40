// sd_notify calls (see systemd_notify.hpp). Stateless, any thread; a WatchdogPetter belongs to the
// one loop that pets it.
#include "depthfuse/daemon/systemd_notify.hpp"

#include <systemd/sd-daemon.h>

namespace depthfuse::daemon {

void notify_ready(const std::string& status_text) {
  const std::string msg = "READY=1\nSTATUS=" + status_text;
  sd_notify(0, msg.c_str());
}

void notify_stopping() { sd_notify(0, "STOPPING=1"); }

void notify_status(const std::string& status_text) {
  const std::string msg = "STATUS=" + status_text;
  sd_notify(0, msg.c_str());
}

void notify_watchdog() { sd_notify(0, "WATCHDOG=1"); }

std::optional<std::chrono::microseconds> watchdog_interval() {
  uint64_t usec = 0;
  if (sd_watchdog_enabled(0, &usec) > 0 && usec > 0)
    return std::chrono::microseconds(static_cast<int64_t>(usec / 2));
  return std::nullopt;
}

WatchdogPetter::WatchdogPetter() : interval_(watchdog_interval()) {}

void WatchdogPetter::pet() {
  if (!interval_) return;
  const auto now = std::chrono::steady_clock::now();
  if (now - last_ < *interval_) return;
  last_ = now;
  notify_watchdog();
}

}  // namespace depthfuse::daemon
