#include "operator_view.hpp"

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/daemon/heartbeat.hpp"
#include "depthfuse/daemon/operator_command.hpp"
#include "depthfuse/daemon/process_info.hpp"
#include "depthfuse/daemon/status_json.hpp"
#include "depthfuse/graph_correction_t.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/map_delta_t.hpp"
#include "depthfuse/map_request_t.hpp"
#include "keyframe_motions.hpp"

DF_LOG_CATEGORY(OperatorView)

namespace depthfuse::monitor {

namespace {

constexpr const char* kFusionName = "fusion";
constexpr auto kResendPeriod = std::chrono::milliseconds(500);
constexpr auto kCommandTimeout = std::chrono::seconds(3);
constexpr auto kSnapshotRequestPeriod = std::chrono::seconds(2);
constexpr size_t kMaxPendingCommands = 16;

}  // namespace

Result<std::unique_ptr<OperatorView>> OperatorView::start(const WebServerOptions& options,
                                                          lcm::LcmTransport* lcm) {
  std::unique_ptr<OperatorView> view(new OperatorView(lcm));
  OperatorView* v = view.get();
  auto server = WebServer::start(options, &view->store_,
                                 [v](const std::string& action, const std::string& argument) {
                                   return v->queue_command(action, argument);
                                 });
  if (!server) return server.status();
  view->server_ = std::move(*server);
  lcm->subscribe(lcm::kMapChannel, [v](const std::string&, const uint8_t* data, size_t size,
                                       int64_t) { v->on_map(data, size); });
  lcm->subscribe(lcm::kGraphChannel, [v](const std::string&, const uint8_t* data, size_t size,
                                         int64_t) { v->on_graph(data, size); });
  DF_LOG(OperatorView, Info) << "the operator's page is at " << view->server_->url();
  return view;
}

void OperatorView::on_map(const uint8_t* data, size_t size) {
  depthfuse::map_delta_t msg;
  const auto r = lcm::decode_message(data, size, &msg);
  if (r != lcm::DecodeResult::kOk) {
    map_counters_.count(r);
    return;
  }
  bool want = false;
  map_counters_.count(store_.apply(msg, &want) == MapStore::Accepted::kOk
                          ? lcm::DecodeResult::kOk
                          : lcm::DecodeResult::kMalformed);
  want_snapshot_ = want_snapshot_ || want;
}

void OperatorView::on_graph(const uint8_t* data, size_t size) {
  // Refused before it is decoded: no correction of a scan is this large.
  if (size > KeyframeMotions::kMaxEncodedBytes) {
    if (graph_counters_.malformed.fetch_add(1) == 0)
      DF_LOG(OperatorView, Warning) << "graph correction of " << size << " bytes refused (at most "
                                    << KeyframeMotions::kMaxEncodedBytes
                                    << "; further refusals are only counted)";
    return;
  }
  depthfuse::graph_correction_t msg;
  const auto r = lcm::decode_message(data, size, &msg);
  if (r != lcm::DecodeResult::kOk) {
    graph_counters_.count(r);
    return;
  }
  Status problem;
  switch (store_.apply(msg, &problem)) {
    case MapStore::Accepted::kOk:
      ++graph_counters_.received;
      DF_LOG(OperatorView, Info) << "loop closure " << msg.version << " of scan " << msg.scan_id
                                 << ": the camera's path moved up to "
                                 << msg.max_translation_m * 1e3 << " mm";
      return;
    case MapStore::Accepted::kMalformed:
      if (graph_counters_.malformed.fetch_add(1) == 0)
        DF_LOG(OperatorView, Warning) << problem.to_string() << " (further refusals are only counted)";
      return;
    case MapStore::Accepted::kOtherScan:
      if (graph_other_scan_.fetch_add(1) == 0)
        DF_LOG(OperatorView, Warning) << problem.to_string() << ": ignored (further ones are only counted)";
      return;
  }
}

void OperatorView::on_heartbeat(const depthfuse::heartbeat_t& hb) {
  if (hb.name != kFusionName) return;
  std::lock_guard<std::mutex> lock(mutex_);
  for (auto it = pending_.begin(); it != pending_.end(); ++it) {
    if (it->cmd.command_id == hb.last_command_id) {
      pending_.erase(it);
      break;
    }
  }
}

void OperatorView::on_status(const depthfuse::status_t& st) {
  server_->set_status(daemon::status_json(st));
}

Result<int64_t> OperatorView::queue_command(const std::string& action, const std::string& argument) {
  int8_t code = 0;
  if (!daemon::parse_action(action, &code))
    return invalid_argument("unknown action '" + action +
                            "' (start, stop, pause, resume, new, checkpoint)");
  Pending p;
  p.cmd = daemon::make_command(code, kFusionName, argument, "page");
  std::lock_guard<std::mutex> lock(mutex_);
  if (pending_.size() >= kMaxPendingCommands)
    return unavailable("too many commands waiting for the fusion daemon's acknowledgement");
  pending_.push_back(p);
  return p.cmd.command_id;
}

void OperatorView::poll() {
  const auto now = Clock::now();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (auto it = pending_.begin(); it != pending_.end();) {
      if (it->sent && now - it->first_sent > kCommandTimeout) {
        DF_LOG(OperatorView, Warning) << "no acknowledgement from the fusion daemon for the page's "
                                      << "command " << it->cmd.command_id;
        ++commands_unacknowledged_;
        it = pending_.erase(it);
        continue;
      }
      if (!it->sent || now >= it->next_send) {
        if (!it->sent) it->first_sent = now;
        it->sent = true;
        it->next_send = now + kResendPeriod;
        if (auto st = lcm_->publish_message(lcm::kCommandChannel, it->cmd); !st.is_ok())
          DF_LOG(OperatorView, Warning) << st.to_string();
        ++commands_sent_;
      }
      ++it;
    }
  }
  if (want_snapshot_ && now - last_request_ >= kSnapshotRequestPeriod) {
    depthfuse::map_request_t req;
    req.protocol_version = depthfuse::map_request_t::PROTOCOL_VERSION;
    req.utime = now_utime();
    req.request_id = req.utime;
    req.target = kFusionName;
    req.sender = "monitor@" + daemon::host_name();
    if (auto st = lcm_->publish_message(lcm::kMapRequestChannel, req); st.is_ok()) {
      want_snapshot_ = false;
      last_request_ = now;
    }
  }
}

void OperatorView::add_counters(depthfuse::heartbeat_t* hb) const {
  daemon::add_counter(hb, "map_deltas", static_cast<double>(map_counters_.received.load()));
  daemon::add_counter(hb, "map_deltas_malformed", static_cast<double>(map_counters_.malformed.load()));
  daemon::add_counter(hb, "map_preview_points", static_cast<double>(store_.point_count()));
  daemon::add_counter(hb, "graph_corrections_applied", static_cast<double>(graph_counters_.received.load()));
  daemon::add_counter(hb, "graph_corrections_malformed",
                      static_cast<double>(graph_counters_.malformed.load() + graph_counters_.bad_version.load() +
                                          graph_counters_.foreign.load()));
  daemon::add_counter(hb, "graph_corrections_other_scan", static_cast<double>(graph_other_scan_.load()));
  daemon::add_counter(hb, "page_commands_sent", static_cast<double>(commands_sent_));
  daemon::add_counter(hb, "page_commands_unacknowledged", static_cast<double>(commands_unacknowledged_));
  // What the web server refused or dropped (web_limits.hpp).
  const WebCounters& web = server_->counters();
  daemon::add_counter(hb, "web_connections_refused", static_cast<double>(web.connections_refused.load()));
  daemon::add_counter(hb, "web_connections_evicted", static_cast<double>(web.connections_evicted.load()));
  daemon::add_counter(hb, "web_requests_timed_out", static_cast<double>(web.requests_timed_out.load()));
  daemon::add_counter(hb, "web_requests_too_large", static_cast<double>(web.requests_too_large.load()));
  daemon::add_counter(hb, "web_origin_refused", static_cast<double>(web.origin_refused.load()));
  daemon::add_counter(hb, "web_pages_refused", static_cast<double>(web.pages_refused.load()));
  daemon::add_counter(hb, "web_pages_dropped", static_cast<double>(web.pages_dropped.load()));
  daemon::add_counter(hb, "web_client_frames_refused", static_cast<double>(web.client_frames_refused.load()));
  daemon::add_counter(hb, "web_commands_taken", static_cast<double>(web.commands_taken.load()));
  const PageCommandAuth* auth = server_->command_auth();
  daemon::add_counter(hb, "page_commands_need_key", auth ? 1 : 0);
  if (!auth) return;
  const lcm::AuthCounters counters = auth->counters();
  daemon::add_counter(hb, "page_commands_verified", static_cast<double>(counters.verified));
  for (size_t i = 0; i < counters.dropped.size(); ++i)
    daemon::add_counter(hb, std::string("page_commands_refused_") + lcm::to_string(static_cast<lcm::AuthDrop>(i)),
                        static_cast<double>(counters.dropped[i]));
  // The status names the last refusal (the page shows a daemon's last error).
  if (hb->last_error.empty()) hb->last_error = auth->last_refusal();
}

}  // namespace depthfuse::monitor
