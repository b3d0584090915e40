// sd_notify for Type=notify units: READY once running, WATCHDOG while healthy, STATUS for
// `systemctl status`. Every call is a no-op when the process is not run by systemd.
#pragma once

#include <chrono>
#include <optional>
#include <string>

namespace depthfuse::daemon {

void notify_ready(const std::string& status_text);
void notify_stopping();
void notify_status(const std::string& status_text);
void notify_watchdog();

// The interval at which WATCHDOG=1 must be sent (half of WatchdogSec), if the unit has one.
std::optional<std::chrono::microseconds> watchdog_interval();

// Sends WATCHDOG=1 no more often than needed; call from the main loop.
class WatchdogPetter {
 public:
  WatchdogPetter();
  void pet();  // cheap when it is not time yet or there is no watchdog

 private:
  std::optional<std::chrono::microseconds> interval_;
  std::chrono::steady_clock::time_point last_{};
};

}  // namespace depthfuse::daemon
