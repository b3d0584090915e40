// The monitor's side of the operator's page, on the monitor's LCM thread: takes the fusion
// daemon's map deltas and loop closures' corrections (DEPTHFUSE_GRAPH, which move the camera's
// path) into the MapStore (asking for a snapshot when it joined late or missed deltas), hands
// each status to the web server, and sends the page's commands as command_t,
// repeated every 500 ms until the fusion daemon acknowledges them (as `depthfuse scan` does).
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>

#include "depthfuse/command_t.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/transport.hpp"
#include "depthfuse/status_t.hpp"
#include "map_store.hpp"
#include "web_server.hpp"

namespace depthfuse::monitor {

class OperatorView {
 public:
  // Subscribes to the map and graph channels; the server starts serving at once.
  static Result<std::unique_ptr<OperatorView>> start(const WebServerOptions& options,
                                                     lcm::LcmTransport* lcm);

  // The LCM thread.
  void on_heartbeat(const depthfuse::heartbeat_t& hb);  // acknowledgements
  void on_status(const depthfuse::status_t& st);
  void poll();  // resends unacknowledged commands, asks for snapshots
  // Its counters (map deltas, graph corrections, the page's commands sent and refused) and, as the last error, the
  // page's last refused command.
  void add_counters(depthfuse::heartbeat_t* hb) const;

  const std::string& url() const { return server_->url(); }

 private:
  using Clock = std::chrono::steady_clock;
  struct Pending {
    depthfuse::command_t cmd;
    Clock::time_point first_sent, next_send;
    bool sent = false;
  };
  explicit OperatorView(lcm::LcmTransport* lcm) : lcm_(lcm) {}
  void on_map(const uint8_t* data, size_t size);
  void on_graph(const uint8_t* data, size_t size);
  // Any web server thread.
  Result<int64_t> queue_command(const std::string& action, const std::string& argument);

  lcm::LcmTransport* lcm_;
  MapStore store_;
  std::unique_ptr<WebServer> server_;
  lcm::ReceiveCounters map_counters_;
  // Corrections applied (received), refused as broken, too large or of another type or version,
  // and those of another scan or fusion daemon.
  lcm::ReceiveCounters graph_counters_;
  std::atomic<int64_t> graph_other_scan_{0};
  bool want_snapshot_ = true;
  Clock::time_point last_request_{};
  int64_t commands_sent_ = 0, commands_unacknowledged_ = 0;

  std::mutex mutex_;  // guards pending_ (web server threads queue, the LCM thread sends)
  std::deque<Pending> pending_;
};

}  // namespace depthfuse::monitor
