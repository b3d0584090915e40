// The monitor daemon (see monitor_daemon.hpp); everything here runs on run()'s thread.
#include "monitor_daemon.hpp"

#include <algorithm>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/daemon/systemd_notify.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/status_t.hpp"

DF_LOG_CATEGORY(Monitor)

namespace depthfuse::monitor {
namespace {

using depthfuse::heartbeat_t;

// A daemon silent for this many stale timeouts is forgotten (a renamed or retired daemon).
constexpr double kForgetAfterStaleTimeouts = 20.0;
// Bounds on the table, in all and per host: a heartbeat under a new name takes the slot of the
// longest-silent stale daemon (of its host first) when the table is full, and is ignored while
// every slot is alive. So forged names from one host cannot keep a new daemon out for good.
constexpr size_t kMaxDaemons = 64;
constexpr size_t kMaxDaemonsPerHost = 8;
// A real heartbeat is a few hundred bytes; a larger one is refused (and counted as malformed)
// before it is decoded, so that it is never copied into the status the monitor sends.
constexpr size_t kMaxHeartbeatBytes = 16 * 1024;

}  // namespace

MonitorDaemon::MonitorDaemon(const MonitorOptions& options,
                             std::unique_ptr<lcm::LcmTransport> lcm)
    : options_(options), lcm_(std::move(lcm)), self_("monitor") {
  lcm_->subscribe(lcm::kHeartbeatChannel, [this](const std::string&, const uint8_t* data,
                                                   size_t size, int64_t) { on_heartbeat(data, size); });
}

Status MonitorDaemon::serve_page(const WebServerOptions& options) {
  auto page = OperatorView::start(options, lcm_.get());
  if (!page) return page.status();
  page_ = std::move(*page);
  return Status::ok();
}

void MonitorDaemon::on_heartbeat(const uint8_t* data, size_t size) {
  if (size > kMaxHeartbeatBytes) {
    ++counters_.malformed;
    return;
  }
  heartbeat_t hb;
  const auto r = lcm::decode_message(data, size, &hb);
  counters_.count(r);
  if (r != lcm::DecodeResult::kOk) return;
  if (hb.name == self_.name()) return;  // our own, we know it better
  if (page_) page_->on_heartbeat(hb);
  auto it = daemons_.find(hb.name);
  if (it == daemons_.end()) {
    if (!make_room(hb.host)) return;
    it = daemons_.emplace(hb.name, Entry{}).first;
  }
  it->second.last = std::move(hb);
  it->second.received = Clock::now();
  ++it->second.count;
}

bool MonitorDaemon::make_room(const std::string& host) {
  const auto now = Clock::now();
  size_t on_host = 0;
  auto stalest = daemons_.end(), stalest_on_host = daemons_.end();
  for (auto it = daemons_.begin(); it != daemons_.end(); ++it) {
    const bool same_host = it->second.last.host == host;
    on_host += same_host;
    if (stalest == daemons_.end() || it->second.received < stalest->second.received) stalest = it;
    if (same_host && (stalest_on_host == daemons_.end() ||
                      it->second.received < stalest_on_host->second.received))
      stalest_on_host = it;
  }
  auto stale = [&](std::map<std::string, Entry>::iterator it) {
    return std::chrono::duration<double>(now - it->second.received).count() > options_.stale_after_s;
  };
  if (on_host >= kMaxDaemonsPerHost) {
    if (!stale(stalest_on_host)) return false;
    daemons_.erase(stalest_on_host);
  } else if (daemons_.size() >= kMaxDaemons) {
    if (!stale(stalest)) return false;
    daemons_.erase(stalest);
  }
  return true;
}

heartbeat_t MonitorDaemon::own_heartbeat() const {
  heartbeat_t hb = self_.make(heartbeat_t::STATE_RUNNING);
  hb.frames_in = counters_.received.load();
  hb.frames_out = statuses_published_;
  hb.messages_malformed = counters_.malformed.load();
  hb.messages_bad_version = counters_.bad_version.load();
  hb.messages_foreign = counters_.foreign.load();
  hb.input_rate_hz = 0;
  daemon::add_counter(&hb, "daemons", static_cast<double>(daemons_.size()));
  daemon::add_counter(&hb, "status_publish_failures", static_cast<double>(publish_failures_));
  daemon::add_receive_counters(*lcm_, &hb);
  if (page_) page_->add_counters(&hb);
  return hb;
}

void MonitorDaemon::publish_status(Clock::time_point now) {
  depthfuse::status_t st;
  st.protocol_version = depthfuse::status_t::PROTOCOL_VERSION;
  st.utime = now_utime();
  st.monitor_host = daemon::host_name();
  st.stale_after_s = options_.stale_after_s;
  st.messages_malformed = counters_.malformed.load();
  st.messages_bad_version = counters_.bad_version.load();
  st.messages_foreign = counters_.foreign.load();
  for (auto it = daemons_.begin(); it != daemons_.end();) {
    const double age_s = std::chrono::duration<double>(now - it->second.received).count();
    if (age_s > kForgetAfterStaleTimeouts * options_.stale_after_s) {
      it = daemons_.erase(it);
      continue;
    }
    depthfuse::daemon_status_t d;
    d.name = it->first;
    d.alive = age_s <= options_.stale_after_s;
    d.heartbeat_age_s = age_s;
    d.heartbeats = it->second.count;
    d.last = it->second.last;
    st.daemons.push_back(std::move(d));
    ++it;
  }
  depthfuse::daemon_status_t me;
  me.name = self_.name();
  me.alive = true;
  me.heartbeat_age_s = 0;
  me.heartbeats = statuses_published_;
  me.last = own_heartbeat();
  st.daemons.push_back(std::move(me));
  st.num_daemons = static_cast<int32_t>(st.daemons.size());
  if (page_) page_->on_status(st);
  Status sent = lcm_->publish_message(lcm::kStatusChannel, st);
  if (sent.is_ok()) sent = lcm_->publish_message(lcm::kHeartbeatChannel, own_heartbeat());
  if (!sent.is_ok()) {
    // Said once when sending starts failing, then counted until it works again.
    if (publish_failing_ == 0)
      DF_LOG(Monitor, Warning) << "status not sent (further failures are only counted): "
                               << sent.to_string();
    ++publish_failing_;
    ++publish_failures_;
    return;
  }
  publish_failing_ = 0;
  ++statuses_published_;
}

size_t MonitorDaemon::alive(Clock::time_point now) const {
  size_t n = 0;
  for (const auto& [name, e] : daemons_)
    n += std::chrono::duration<double>(now - e.received).count() <= options_.stale_after_s;
  return n;
}

int MonitorDaemon::run(const daemon::ShutdownSignal& shutdown) {
  daemon::notify_ready("monitoring " + lcm_->url());
  daemon::WatchdogPetter watchdog;
  const auto period = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(1.0 / options_.rate_hz));
  auto next = Clock::now();
  while (!shutdown.stop_requested()) {
    const auto now = Clock::now();
    if (now >= next) {
      publish_status(now);
      watchdog.pet();
      daemon::notify_status(std::to_string(alive(now)) + "/" + std::to_string(daemons_.size()) +
                            " daemons alive");
      next += period;
      if (next < now) next = now + period;
    }
    const int wait_ms = static_cast<int>(
        std::chrono::duration_cast<std::chrono::milliseconds>(next - Clock::now()).count());
    if (page_) page_->poll();
    auto r = lcm_->handle(std::max(1, std::min(wait_ms, 100)));
    if (!r) {
      DF_LOG(Monitor, Error) << r.status().to_string();
      shutdown.sleep_for(0.1);
    }
  }
  daemon::notify_stopping();
  return 0;
}

}  // namespace depthfuse::monitor
