// depthfuse-monitor: listens to every daemon's heartbeat and publishes the appliance's status
// (status_t on DEPTHFUSE_STATUS) at monitor.publish_rate_hz: per daemon its liveness (stale after
// monitor.stale_after_s without a heartbeat), rates, drops, point count, memory and last error.
// The monitor's own heartbeat is in the status too.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>

#include "depthfuse/app_config.hpp"
#include "depthfuse/base/clock.hpp"
#include "depthfuse/daemon/heartbeat.hpp"
#include "depthfuse/daemon/signals.hpp"
#include "depthfuse/daemon/systemd_notify.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/transport.hpp"
#include "depthfuse/status_t.hpp"

namespace {

using Clock = std::chrono::steady_clock;
using depthfuse::heartbeat_t;
namespace lcmio = depthfuse::lcmio;
namespace dd = depthfuse::daemon;

// A daemon silent for this many stale timeouts is forgotten (a renamed or retired daemon).
constexpr double kForgetAfterStaleTimeouts = 20.0;
constexpr size_t kMaxDaemons = 64;

struct Entry {
  heartbeat_t last;
  Clock::time_point received;
  int64_t count = 0;
};

void usage(FILE* out) {
  std::fprintf(out,
      "usage: depthfuse-monitor [--lcm URL] [--config FILE] [--stale-after S] [--rate HZ]\n"
      "  --stale-after S  a daemon without a heartbeat for S seconds is reported stale\n"
      "                   (default: the config's monitor.stale_after_s)\n"
      "  --rate HZ        status messages per second (default: monitor.publish_rate_hz)\n");
}

bool parse_positive(const char* text, double* out) {
  char* end = nullptr;
  const double v = std::strtod(text, &end);
  if (*end != '\0' || !(v > 0) || !std::isfinite(v)) return false;
  *out = v;
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  std::string url, config_path, stale_text, rate_text;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--help" || a == "-h") {
      usage(stdout);
      return 0;
    }
    if (i + 1 >= argc || (a != "--lcm" && a != "--config" && a != "--stale-after" && a != "--rate")) {
      std::fprintf(stderr, "depthfuse-monitor: bad option '%s'\n", a.c_str());
      usage(stderr);
      return 2;
    }
    const std::string v = argv[++i];
    if (a == "--lcm") url = v;
    else if (a == "--config") config_path = v;
    else if (a == "--stale-after") stale_text = v;
    else rate_text = v;
  }
  auto& shutdown = dd::ShutdownSignal::install();
  depthfuse::AppConfig config;
  if (!config_path.empty()) {
    auto loaded = depthfuse::load_app_config(config_path);
    if (!loaded) {
      std::fprintf(stderr, "depthfuse-monitor: %s\n", loaded.status().to_string().c_str());
      return 2;
    }
    config = std::move(loaded).value();
  }
  if (url.empty()) url = config.lcm.url;
  double stale_after_s = config.monitor.stale_after_s;
  double rate_hz = config.monitor.publish_rate_hz;
  if (!stale_text.empty() && !parse_positive(stale_text.c_str(), &stale_after_s)) {
    std::fprintf(stderr, "depthfuse-monitor: --stale-after must be a positive number of seconds\n");
    return 2;
  }
  if (!rate_text.empty() && !parse_positive(rate_text.c_str(), &rate_hz)) {
    std::fprintf(stderr, "depthfuse-monitor: --rate must be a positive number\n");
    return 2;
  }

  std::vector<std::string> warnings;
  auto opened = lcmio::LcmTransport::open(url, &warnings);
  for (const auto& w : warnings) std::fprintf(stderr, "depthfuse-monitor: warning: %s\n", w.c_str());
  if (!opened) {
    std::fprintf(stderr, "depthfuse-monitor: %s\n", opened.status().to_string().c_str());
    return 1;
  }
  auto lcm = std::move(opened).value();

  dd::HeartbeatBase self("monitor");
  lcmio::ReceiveCounters counters;
  std::map<std::string, Entry> daemons;  // only touched by this thread (LCM dispatches here)
  int64_t statuses_published = 0;

  lcm->subscribe(lcmio::kHeartbeatChannel, [&](const std::string&, const uint8_t* data, size_t size,
                                               int64_t) {
    heartbeat_t hb;
    const auto r = lcmio::decode_message(data, size, &hb);
    counters.count(r);
    if (r != lcmio::DecodeResult::kOk) return;
    if (hb.name == self.name()) return;  // our own, we know it better
    auto it = daemons.find(hb.name);
    if (it == daemons.end()) {
      if (daemons.size() >= kMaxDaemons) return;
      it = daemons.emplace(hb.name, Entry{}).first;
    }
    it->second.last = std::move(hb);
    it->second.received = Clock::now();
    ++it->second.count;
  });

  auto make_own_heartbeat = [&] {
    heartbeat_t hb = self.make(heartbeat_t::STATE_RUNNING);
    hb.frames_in = counters.received.load();
    hb.frames_out = statuses_published;
    hb.messages_malformed = counters.malformed.load();
    hb.messages_bad_version = counters.bad_version.load();
    hb.messages_foreign = counters.foreign.load();
    hb.input_rate_hz = 0;
    dd::add_counter(&hb, "daemons", static_cast<double>(daemons.size()));
    return hb;
  };

  auto publish_status = [&] {
    const auto now = Clock::now();
    depthfuse::status_t st;
    st.protocol_version = depthfuse::status_t::PROTOCOL_VERSION;
    st.utime = depthfuse::now_utime();
    st.monitor_host = dd::host_name();
    st.stale_after_s = stale_after_s;
    st.messages_malformed = counters.malformed.load();
    st.messages_bad_version = counters.bad_version.load();
    st.messages_foreign = counters.foreign.load();
    for (auto it = daemons.begin(); it != daemons.end();) {
      const double age_s = std::chrono::duration<double>(now - it->second.received).count();
      if (age_s > kForgetAfterStaleTimeouts * stale_after_s) {
        it = daemons.erase(it);
        continue;
      }
      depthfuse::daemon_status_t d;
      d.name = it->first;
      d.alive = age_s <= stale_after_s;
      d.heartbeat_age_s = age_s;
      d.heartbeats = it->second.count;
      d.last = it->second.last;
      st.daemons.push_back(std::move(d));
      ++it;
    }
    depthfuse::daemon_status_t me;
    me.name = self.name();
    me.alive = true;
    me.heartbeat_age_s = 0;
    me.heartbeats = statuses_published;
    me.last = make_own_heartbeat();
    st.daemons.push_back(std::move(me));
    st.num_daemons = static_cast<int32_t>(st.daemons.size());
    (void)lcm->publish_message(lcmio::kStatusChannel, st);
    (void)lcm->publish_message(lcmio::kHeartbeatChannel, make_own_heartbeat());
    ++statuses_published;
  };

  dd::notify_ready("monitoring " + url);
  dd::WatchdogPetter watchdog;
  const auto period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / rate_hz));
  auto next = Clock::now();
  while (!shutdown.stop_requested()) {
    const auto now = Clock::now();
    if (now >= next) {
      publish_status();
      watchdog.pet();
      size_t alive = 0;
      for (const auto& [name, e] : daemons)
        alive += std::chrono::duration<double>(now - e.received).count() <= stale_after_s;
      dd::notify_status(std::to_string(alive) + "/" + std::to_string(daemons.size()) +
                        " daemons alive");
      next += period;
      if (next < now) next = now + period;
    }
    const int wait_ms = static_cast<int>(
        std::chrono::duration_cast<std::chrono::milliseconds>(next - Clock::now()).count());
    auto r = lcm->handle(std::max(1, std::min(wait_ms, 100)));
    if (!r) {
      std::fprintf(stderr, "depthfuse-monitor: %s\n", r.status().to_string().c_str());
      shutdown.sleep_for(0.1);
    }
  }
  dd::notify_stopping();
  return 0;
}
