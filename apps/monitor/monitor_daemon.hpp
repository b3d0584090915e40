// The monitor daemon: every daemon's heartbeat in, the appliance's status (status_t on
// DEPTHFUSE_STATUS) out at a fixed rate: per daemon its liveness (stale after stale_after_s
// without a heartbeat), its last heartbeat and how many it sent; the monitor's own heartbeat is in
// the status too. One thread, run()'s: LCM calls the heartbeat handler from inside handle(), so the
// table of daemons needs no lock.
#pragma once

#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <string>

#include "depthfuse/daemon/heartbeat.hpp"
#include "depthfuse/daemon/signals.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/transport.hpp"
#include "operator_view.hpp"

namespace depthfuse::monitor {

struct MonitorOptions {
  double stale_after_s = 3.0;  // a daemon without a heartbeat for this long is not alive
  double rate_hz = 1.0;        // status messages per second
};

class MonitorDaemon {
 public:
  MonitorDaemon(const MonitorOptions& options, std::unique_ptr<lcm::LcmTransport> lcm);

  // Serves the operator's page (before run()); an error says why it cannot.
  Status serve_page(const WebServerOptions& options);

  // Publishes until `shutdown` is requested; the exit code.
  int run(const daemon::ShutdownSignal& shutdown);

 private:
  using Clock = std::chrono::steady_clock;
  struct Entry {
    depthfuse::heartbeat_t last;
    Clock::time_point received;
    int64_t count = 0;
  };

  void on_heartbeat(const uint8_t* data, size_t size);
  // Room in the table for a new daemon on `host`: false when its host's slots, or all slots, are
  // taken by daemons that are alive; else the longest-silent stale one gives up its slot.
  bool make_room(const std::string& host);
  depthfuse::heartbeat_t own_heartbeat() const;
  void publish_status(Clock::time_point now);
  size_t alive(Clock::time_point now) const;

  MonitorOptions options_;
  std::unique_ptr<lcm::LcmTransport> lcm_;
  daemon::HeartbeatBase self_;
  lcm::ReceiveCounters counters_;
  std::map<std::string, Entry> daemons_;
  int64_t statuses_published_ = 0;
  int64_t publish_failures_ = 0;  // status or heartbeat not sent, in all
  int64_t publish_failing_ = 0;   // in a row, up to now
  std::unique_ptr<OperatorView> page_;  // null unless serve_page() was called
};

}  // namespace depthfuse::monitor
