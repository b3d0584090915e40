// depthfuse status [--watch] [--json] [--lcm URL] [--timeout S]: the monitor's status, from any
// host on the LCM network.
#if __has_include("depthfuse/status_t.hpp")
#include <chrono>
#include <cinttypes>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "command.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/daemon/heartbeat.hpp"
#include "depthfuse/daemon/startup.hpp"
#include "depthfuse/daemon/status_json.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/transport.hpp"
#include "depthfuse/status_t.hpp"

DF_LOG_CATEGORY(Status)

namespace {

namespace daemon = depthfuse::daemon;
namespace lcm = depthfuse::lcm;
using depthfuse::heartbeat_t;

void print_json(const depthfuse::status_t& st) {
  std::printf("%s\n", daemon::status_json(st).c_str());
  std::fflush(stdout);
}

void print_table(const depthfuse::status_t& st) {
  std::printf("monitor on %s, stale after %.1f s", st.monitor_host.c_str(), st.stale_after_s);
  if (st.messages_malformed + st.messages_bad_version + st.messages_foreign)
    std::printf(" (heartbeats unreadable: %" PRId64 " malformed, %" PRId64 " unknown version, %" PRId64
                " foreign)", st.messages_malformed, st.messages_bad_version, st.messages_foreign);
  std::printf("\n");
  if (const auto open = daemon::unsigned_daemons(st); !open.empty()) {
    std::string names;
    for (const auto& name : open) names += (names.empty() ? "" : ", ") + name;
    std::printf("NO RIG KEY: %s sign and check nothing; anyone who reaches the LCM bus can send "
                "them frames and commands (lcm.key_file; docs/protocol.md, \"Authentication\")\n",
                names.c_str());
  }
  std::printf("%-10s %-6s %-9s %-16s %8s %8s %8s %8s %8s %6s %10s %8s  %s\n", "daemon", "alive",
              "state", "host:pid", "in Hz", "out Hz", "dropped", "lost", "bad msg", "queue",
              "points", "RSS MiB", "scan / last error");
  for (const auto& d : st.daemons) {
    const auto& h = d.last;
    const std::string where = h.host + ":" + std::to_string(h.pid);
    const int64_t bad = h.messages_malformed + h.messages_bad_version + h.messages_foreign +
                        h.frames_out_of_order;
    char queue[32];
    if (h.queue_capacity > 0)
      std::snprintf(queue, sizeof(queue), "%d/%d", h.queue_depth, h.queue_capacity);
    else
      std::snprintf(queue, sizeof(queue), "-");
    std::string tail = h.scan_id.empty() ? "" : "scan " + h.scan_id;
    if (!h.last_error.empty()) tail += (tail.empty() ? "" : "; ") + std::string("last error: ") + h.last_error;
    // The fusion daemon's tracking (registration.hpp's TrackingState), when it is not good.
    if (const double tracking = daemon::counter_value(h, "tracking_state"); tracking > 0)
      tail += (tail.empty() ? "" : "; ") + std::string("tracking ") +
              (tracking >= 2 ? "LOST" : "uncertain") + " (" +
              std::to_string(static_cast<int64_t>(daemon::counter_value(h, "frames_lost_tracking"))) +
              " frames lost so far)";
    // The fusion daemon fell behind its camera and tracked frames without fusing them: the map is
    // thinner than the frame rate, the track is whole (fusion_daemon.shed_fusion_queue_share).
    if (const double shed = daemon::counter_value(h, "frames_fusion_shed"); shed > 0) {
      char tracked_only[96];
      std::snprintf(tracked_only, sizeof(tracked_only), "%.0f frames tracked only (fusion behind)",
                    shed);
      tail += (tail.empty() ? "" : "; ") + std::string(tracked_only);
    }
    // The fusion daemon's loop closures: the scan's map was corrected where the camera came back.
    if (const double loops = daemon::counter_value(h, "loop_closures"); loops > 0) {
      char closed[128];
      std::snprintf(closed, sizeof(closed), "%.0f loop closures, %.0f corrections (the last %.1f mm)",
                    loops, daemon::counter_value(h, "graph_corrections"),
                    daemon::counter_value(h, "last_correction_mm"));
      tail += (tail.empty() ? "" : "; ") + std::string(closed);
    }
    if (const std::string refused = daemon::auth_refusals(h); !refused.empty())
      tail += (tail.empty() ? "" : "; ") + std::string("refused unsigned: ") + refused;
    char alive[16];
    if (d.alive)
      std::snprintf(alive, sizeof(alive), "yes");
    else
      std::snprintf(alive, sizeof(alive), "STALE");
    std::printf("%-10s %-6s %-9s %-16s %8.1f %8.1f %8" PRId64 " %8" PRId64 " %8" PRId64
                " %6s %10" PRId64 " %8.1f  %s\n",
                d.name.c_str(), alive, daemon::state_name(h.state), where.c_str(), h.input_rate_hz,
                h.output_rate_hz, h.frames_dropped, h.frames_lost, bad, queue, h.point_count,
                h.rss_bytes / (1024.0 * 1024.0), tail.c_str());
  }
  std::fflush(stdout);
}

constexpr const char* kUsage =
    "usage: depthfuse status [--watch] [--json] [--lcm URL] [--config FILE] [--timeout S]\n"
    "Prints the appliance status published by depthfuse-monitor. --watch keeps\n"
    "printing each update; --json prints one JSON object per status.\n";

int cmd_status(int argc, char** argv) {
  daemon::Startup startup({"depthfuse status", kUsage, {"timeout"}, {"watch", "json"}, {}, 0},
                          argc, argv);
  if (auto code = startup.exit_code()) return *code;
  const bool watch = startup.args().has("watch"), json = startup.args().has("json");
  double timeout_s = 3.0;
  std::string error;
  if (!startup.args().get_double("timeout", &timeout_s, &error, daemon::positive()))
    return startup.usage_error(error);
  auto bus = startup.open_lcm();
  if (!bus) return 1;
  bool got = false;
  lcm::ReceiveCounters counters;
  bus->subscribe(lcm::kStatusChannel, [&](const std::string&, const uint8_t* data, size_t size,
                                            int64_t) {
    depthfuse::status_t st;
    const auto r = lcm::decode_message(data, size, &st);
    counters.count(r);
    if (r != lcm::DecodeResult::kOk) {
      DF_LOG(Status, Warning) << "unreadable status message (" << lcm::to_string(r) << ")";
      return;
    }
    if (got && !watch) return;
    got = true;
    if (json)
      print_json(st);
    else {
      if (watch) std::printf("\n");
      print_table(st);
    }
  });
  using Clock = std::chrono::steady_clock;
  auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                     std::chrono::duration<double>(timeout_s));
  while (watch || !got) {
    if (!got && Clock::now() > deadline) {
      char waited[32];
      std::snprintf(waited, sizeof waited, "%.1f", timeout_s);
      DF_LOG(Status, Error) << "no status on " << bus->url() << " within " << waited
                            << " s: is depthfuse-monitor running on the same LCM URL (and "
                               "multicast reaching this host)?";
      return 1;
    }
    auto r = bus->handle(100);
    if (!r) {
      DF_LOG(Status, Error) << r.status().to_string();
      return 1;
    }
  }
  return 0;
}

}  // namespace

DF_REGISTER_COMMAND(status, "status", "status [--watch] [--json] [--lcm URL]",
                    "print the live appliance's status (from depthfuse-monitor)", cmd_status);
#endif
