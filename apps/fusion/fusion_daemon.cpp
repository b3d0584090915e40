// The fusion daemon (see fusion_daemon.hpp): run() and the LCM handlers are the receive thread;
// worker_loop() and what it calls (execute, start_scan, stop_scan, fuse) the worker thread. Either
// publishes the heartbeat: what it reads is atomic or under mutex_.
#include "fusion_daemon.hpp"

#include <algorithm>
#include <filesystem>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/color_frame_t.hpp"
#include "depthfuse/daemon/moving_average.hpp"
#include "depthfuse/daemon/process_info.hpp"
#include "depthfuse/daemon/systemd_notify.hpp"
#include "depthfuse/depth_frame_t.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/frame_codec.hpp"
#include "depthfuse/lcm/pose_messages.hpp"
#include "depthfuse/graph_correction_t.hpp"
#include "depthfuse/ply.hpp"
#include "depthfuse/pose2_t.hpp"
#include "depthfuse/pose_t.hpp"
#include "depthfuse/trajectory.hpp"

DF_LOG_CATEGORY(Fusion)

namespace depthfuse::fusiond {

namespace {

using depthfuse::command_t;
using depthfuse::heartbeat_t;
using Clock = std::chrono::steady_clock;

constexpr size_t kMaxPublishers = 16;
constexpr size_t kRecentCommands = 64;
using daemon::ewma;  // the heartbeat's moving averages, over ~10 frames

// Saving a very large scan may take a while; a frame takes well under a second.
constexpr double kStuckWorkerS = 60.0;

const char* action_name(int8_t a) {
  switch (a) {
    case command_t::ACTION_START: return "start";
    case command_t::ACTION_STOP: return "stop";
    case command_t::ACTION_PAUSE: return "pause";
    case command_t::ACTION_RESUME: return "resume";
    case command_t::ACTION_NEW_SCAN: return "new scan";
    case command_t::ACTION_CHECKPOINT_NOW: return "checkpoint";
  }
  return "unknown";
}

}  // namespace

FusionDaemon::FusionDaemon(const AppConfig& config, const DaemonOptions& options,
                           std::unique_ptr<lcm::LcmTransport> lcm,
                           std::unique_ptr<CheckpointSink> sink)
    : config_(config),
      budget_(MemoryBudget::of(config)),
      options_(options),
      lcm_(std::move(lcm)),
      sink_(std::move(sink)),
      hb_base_(options.name),
      queue_(static_cast<size_t>(std::max(1, config.fusion.queue_capacity_frames))),
      preview_(config.map_preview, options.name, lcm_.get()),
      state_(heartbeat_t::STATE_IDLE),
      session_(config_, *sink_) {
  frame_limits_.max_width = config.fusion.max_frame_width;
  frame_limits_.max_height = config.fusion.max_frame_height;
  frame_limits_.max_pose_hint_m = config.fusion.workspace_radius_m;
  lcm_->subscribe(lcm::kDepthChannel, [this](const std::string&, const uint8_t* d, size_t n,
                                               int64_t) { on_depth(d, n); });
  lcm_->subscribe(lcm::kColorChannel, [this](const std::string&, const uint8_t* d, size_t n,
                                               int64_t) { on_color(d, n); });
  lcm_->subscribe(lcm::kCommandChannel, [this](const std::string&, const uint8_t* d, size_t n,
                                                 int64_t) { on_command(d, n); });
  lcm_->subscribe(lcm::kMapRequestChannel, [this](const std::string&, const uint8_t* d, size_t n,
                                                    int64_t) { preview_.on_request(d, n, &counters_); });
}

FusionDaemon::~FusionDaemon() {
  stopping_ = true;
  queue_.wake();
  if (worker_.joinable()) worker_.join();
}

void FusionDaemon::set_error(const std::string& e) {
  std::lock_guard<std::mutex> lock(mutex_);
  last_error_ = e;
}

// ---------------------------------------------------------------- receive thread

void FusionDaemon::on_color(const uint8_t* data, size_t size) {
  depthfuse::color_frame_t msg;
  const auto r = lcm::decode_message(data, size, &msg);
  if (r != lcm::DecodeResult::kOk) {
    counters_.count(r);
    return;
  }
  if (state_.load() != heartbeat_t::STATE_RUNNING) return;
  if (!follows(msg.sensor_serial)) return;  // counted with its depth frame
  ColorImage color;
  if (auto st = lcm::decode_color_frame(msg, &color, frame_limits_); !st.is_ok()) {
    ++counters_.malformed;
    set_error(st.message());
    return;
  }
  pending_color_[msg.sequence] = std::move(color);
  while (pending_color_.size() > kPendingColorFrames) pending_color_.erase(pending_color_.begin());
}

void FusionDaemon::on_depth(const uint8_t* data, size_t size) {
  depthfuse::depth_frame_t msg;
  const auto r = lcm::decode_message(data, size, &msg);
  if (r != lcm::DecodeResult::kOk) {
    counters_.count(r);
    return;
  }
  if (!follows(msg.sensor_serial)) {
    ++frames_other_serial_;
    return;
  }
  QueuedFrame item;
  lcm::DepthFrameNotes notes;
  if (auto st = lcm::decode_depth_frame(msg, &item.frame, frame_limits_, nullptr, &notes);
      !st.is_ok()) {
    ++counters_.malformed;
    set_error(st.message());
    return;
  }
  if (!notes.pose_hint_refused.empty()) {
    ++counters_.pose_hints_refused;  // the frame goes on without it
    set_error(notes.pose_hint_refused);
  }
  // Per publisher, so that two captures on one channel do not look like chaos to each other.
  const std::string publisher = msg.source + "|" + msg.sensor_serial;
  if (sequences_.size() >= kMaxPublishers && !sequences_.count(publisher)) sequences_.clear();
  const auto seen = sequences_[publisher].observe(msg.sequence);
  counters_.count(seen);
  // A late frame: its pose would be predicted from a newer one. Counted, not fused.
  if (seen.verdict == lcm::SequenceTracker::Verdict::kOutOfOrder) return;
  ++counters_.received;
  ++frames_in_;
  in_rate_.add();
  if (state_.load() != heartbeat_t::STATE_RUNNING) {
    ++frames_ignored_;
    return;
  }
  auto color = pending_color_.find(msg.sequence);
  if (color != pending_color_.end()) {
    if (color->second.width == item.frame.depth.width &&
        color->second.height == item.frame.depth.height) {
      item.frame.color = std::move(color->second);
    } else {
      // Not registered to the depth pixel for pixel: the depth is fused without it. Said once,
      // counted always (heartbeat counter color_wrong_size).
      const std::string e = "colour frame " + std::to_string(msg.sequence) + " is " +
                            std::to_string(color->second.width) + "x" +
                            std::to_string(color->second.height) + ", its depth frame " +
                            std::to_string(item.frame.depth.width) + "x" +
                            std::to_string(item.frame.depth.height) +
                            ": colour must be registered to depth pixel for pixel; fused without it";
      if (color_wrong_size_++ == 0) DF_LOG(Fusion, Warning) << e;
      set_error(e);
    }
    pending_color_.erase(pending_color_.begin(), std::next(color));
  }
  item.publish_utime = msg.publish_utime;
  queue_.push(std::move(item));  // drops (and counts) the oldest frame when full
}

void FusionDaemon::on_command(const uint8_t* data, size_t size) {
  depthfuse::command_t cmd;
  const auto r = lcm::decode_message(data, size, &cmd);
  if (r != lcm::DecodeResult::kOk) {
    counters_.count(r);
    return;
  }
  if (!cmd.target.empty() && cmd.target != options_.name) return;
  bool acknowledge_again = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    // The client repeats a command until it is acknowledged: a repeat is never carried out twice.
    // The last one is acknowledged again; an older one (a straggler) is ignored.
    const bool seen = std::find(recent_command_ids_.begin(), recent_command_ids_.end(),
                                cmd.command_id) != recent_command_ids_.end();
    if (seen) {
      acknowledge_again = cmd.command_id == ack_.id;
    } else {
      recent_command_ids_.push_back(cmd.command_id);
      if (recent_command_ids_.size() > kRecentCommands) recent_command_ids_.pop_front();
      commands_.push_back(cmd);
      queue_.wake();
    }
  }
  if (acknowledge_again) publish_heartbeat();
}

// ---------------------------------------------------------------- worker thread

FusionProgress FusionDaemon::progress() const {
  return FusionProgress{static_cast<uint64_t>(frames_in_.load()),
                        static_cast<uint64_t>(frames_fused_.load()),
                        static_cast<uint64_t>(queue_.dropped()),
                        static_cast<uint64_t>(frames_fusion_shed_.load()),
                        static_cast<uint64_t>(frames_lost_tracking_.load())};
}

Status FusionDaemon::start_scan(const std::string& requested_name, std::string* message) {
  Result<std::string> started = session_.start(requested_name);
  if (!started) return started.status();
  *message = *started;
  point_count_ = static_cast<int64_t>(session_.point_count());
  frames_ignored_ += static_cast<int64_t>(queue_.clear());  // not part of this scan
  {
    std::lock_guard<std::mutex> lock(mutex_);
    scan_id_ = session_.scan_id();
  }
  state_ = heartbeat_t::STATE_RUNNING;
  return Status::ok();
}

Status FusionDaemon::stop_scan(const std::string& reason, std::string* message) {
  if (!session_.active()) return invalid_argument("no scan is running");
  state_ = heartbeat_t::STATE_STOPPING;
  frames_ignored_ += static_cast<int64_t>(queue_.clear());
  Result<ScanSession::Saved> saved = session_.stop(reason, progress());
  if (!saved) {
    // Never lose a scan: keep it, paused, so that the operator can fix the cause and stop again.
    state_ = heartbeat_t::STATE_PAUSED;
    set_error(saved.status().to_string());
    return Status(saved.status().code(), saved.status().message() +
                                             "; the scan is kept in memory, paused: fix the "
                                             "problem and stop again");
  }
  *message = saved->message;
  if (!saved->store.is_ok()) set_error(saved->store.to_string());
  point_count_ = 0;
  state_ = heartbeat_t::STATE_IDLE;
  std::lock_guard<std::mutex> lock(mutex_);
  scan_id_.clear();
  return Status::ok();
}

void FusionDaemon::execute(const command_t& cmd) {
  std::string message;
  Status st = Status::ok();
  const int8_t state = state_.load();
  const bool in_scan = session_.active();
  switch (cmd.action) {
    case command_t::ACTION_START:
      if (!in_scan) {
        st = start_scan(cmd.argument, &message);
      } else if (state == heartbeat_t::STATE_PAUSED) {
        state_ = heartbeat_t::STATE_RUNNING;
        message = "scan " + session_.scan_id() + " resumed";
      } else {
        message = "scan " + session_.scan_id() + " is already running";
      }
      break;
    case command_t::ACTION_STOP:
      st = stop_scan("final", &message);
      break;
    case command_t::ACTION_PAUSE:
      if (!in_scan) {
        st = invalid_argument("no scan is running");
      } else {
        state_ = heartbeat_t::STATE_PAUSED;
        frames_ignored_ += static_cast<int64_t>(queue_.clear());
        message = "scan " + session_.scan_id() + " paused";
      }
      break;
    case command_t::ACTION_RESUME:
      if (!in_scan) {
        st = invalid_argument("no scan is running");
      } else {
        state_ = heartbeat_t::STATE_RUNNING;
        message = "scan " + session_.scan_id() + " resumed";
      }
      break;
    case command_t::ACTION_NEW_SCAN: {
      std::string saved;
      // Checked before the running scan is stopped: a refused `new` leaves it running.
      st = session_.may_start();
      if (st.is_ok() && in_scan) st = stop_scan("final", &saved);
      if (st.is_ok()) st = start_scan(cmd.argument, &message);
      if (st.is_ok() && !saved.empty()) message = saved + "; " + message;
      break;
    }
    case command_t::ACTION_CHECKPOINT_NOW:
      if (!in_scan) {
        st = invalid_argument("no scan is running");
      } else {
        st = session_.checkpoint("command", progress());
        message = sink_->durable() ? "checkpoint written (" + sink_->describe() + ")"
                                   : "checkpoint: no checkpoint store in this build (nothing written)";
      }
      break;
    default:
      st = invalid_argument("unknown action " + std::to_string(cmd.action));
  }
  DF_LOG(Fusion, Info) << "command " << action_name(cmd.action) << " from " << cmd.sender << ": "
                       << (st.is_ok() ? message : st.to_string());
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ack_.id = cmd.command_id;
    ack_.result = st.is_ok() ? heartbeat_t::COMMAND_RESULT_OK : heartbeat_t::COMMAND_RESULT_REJECTED;
    ack_.message = st.is_ok() ? message : st.to_string();
    if (!st.is_ok() && st.code() != StatusCode::kInvalidArgument) last_error_ = st.to_string();
  }
  publish_heartbeat();  // the acknowledgement, at once
}

void FusionDaemon::fuse(QueuedFrame& item, FrameWork work) {
  Result<FrameOutcome> outcome = session_.process(item.frame, work);
  if (!outcome) {
    ++process_errors_;
    set_error("frame " + std::to_string(item.frame.sequence) + ": " + outcome.status().to_string());
    return;
  }
  if (!outcome->store_status.is_ok())
    set_error("checkpoint store: " + outcome->store_status.to_string());
  if (outcome->correction) publish_correction(*outcome->correction);
  const FrameReport& rep = outcome->report;
  count_tracking(rep);
  preview_.frame_tracked(static_cast<int8_t>(rep.tracking));
  if (rep.fused()) {
    point_count_ = static_cast<int64_t>(session_.point_count());
    ++frames_fused_;
    out_rate_.add();
    preview_.frame_fused(item.frame.sequence, rep.T_world_cam, rep.registered);
    if (rep.registered) ++registered_;
    else if (session_.trajectory().size() > 1) ++icp_failures_;
  } else if (rep.fusion_shed) {
    ++frames_fusion_shed_;
  }
  publish_frame(item, rep);
}

// A loop closure moved the keyframes (and so every pose published before): viewers move theirs.
void FusionDaemon::publish_correction(const AppliedCorrection& correction) {
  const depthfuse::graph_correction_t msg = lcm::make_graph_correction(
      correction, [this](uint32_t frame_id) { return session_.sequence_of(frame_id); },
      options_.name, session_.scan_id(), now_utime());
  if (auto st = lcm_->publish_message(lcm::kGraphChannel, msg); !st.is_ok()) set_error(st.message());
  last_correction_mm_ = correction.max_translation_m * 1e3;
  DF_LOG(Fusion, Info) << "loop closure " << correction.version << ": " << correction.loops
                       << " loops in the pose graph, keyframes moved up to "
                       << correction.max_translation_m * 1e3 << " mm";
}

// A lost frame's pose is unknown: it was not fused, and it has no place in the trajectory, the pose
// channel or the scan file. The next frame is tracked from the last frame fused. Viewers see the
// loss on DEPTHFUSE_POSE2, with the last fused pose.
void FusionDaemon::publish_frame(const QueuedFrame& item, const FrameReport& rep) {
  lcm::FramePublication publication;
  publication.frame_publish_utime = item.publish_utime;
  publication.scan_id = session_.scan_id();
  publication.map_points = point_count_.load();
  publication.publish_utime = now_utime();
  const depthfuse::pose2_t pose2 = lcm::make_pose2(
      item.frame, rep, session_.reconstructor()->last_pose().value_or(Pose::Identity()),
      publication);
  if (rep.fused()) {
    if (auto st = lcm_->publish_message(lcm::kPoseChannel, pose2.pose); !st.is_ok())
      set_error(st.message());
  }
  if (auto st = lcm_->publish_message(lcm::kPose2Channel, pose2); !st.is_ok())
    set_error(st.message());
  if (!rep.fused()) return;
  std::lock_guard<std::mutex> lock(mutex_);
  if (item.publish_utime > 0)
    ewma(&mean_latency_ms_, (publication.publish_utime - item.publish_utime) * 1e-3);
  ewma(&mean_prefilter_ms_, rep.prefilter_ms);
  ewma(&mean_registration_ms_, rep.registration_ms);
  ewma(&mean_fusion_ms_, rep.fusion_ms);
  if (rep.registered) {
    ewma(&mean_fitness_, rep.registration.fitness);
    ewma(&mean_rmse_m_, rep.registration.rmse_m);
  }
}

void FusionDaemon::count_tracking(const FrameReport& rep) {
  const TrackingState state = rep.tracking;
  tracking_state_ = static_cast<int>(state);
  if (rep.relocalised) ++relocalisations_;
  relocalisations_refused_ += rep.relocalisations_out_of_reach;
  relocalisations_ambiguous_ += rep.relocalisations_ambiguous;
  switch (state) {
    case TrackingState::kTracked: ++frames_tracked_; break;
    case TrackingState::kUncertain: ++frames_uncertain_; break;
    case TrackingState::kLost: ++frames_lost_tracking_; break;
  }
  // Said once per loss, not per frame: the heartbeat counts the frames.
  if (state == TrackingState::kLost) {
    if (frames_lost_in_a_row_++ == 0)
      DF_LOG(Fusion, Warning) << "tracking lost: frames are not fused until the camera sees the "
                                 "map again";
  } else if (rep.relocalised) {
    // The frame was lost by tracking and found among the keyframes: it counts as tracked.
    DF_LOG(Fusion, Info) << "tracking lost, and relocalised among the keyframes after "
                         << frames_lost_in_a_row_ << " frames lost before this one (search "
                         << rep.relocalisation_ms << " ms)";
    frames_lost_in_a_row_ = 0;
  } else if (frames_lost_in_a_row_ > 0) {
    DF_LOG(Fusion, Info) << "tracking regained after " << frames_lost_in_a_row_ << " lost frames";
    frames_lost_in_a_row_ = 0;
  }
}

void FusionDaemon::worker_loop() {
  for (;;) {
    std::deque<command_t> commands;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      commands.swap(commands_);
    }
    for (const auto& cmd : commands) {
      worker_busy_since_ns_ = steady_ns();
      execute(cmd);
      worker_busy_since_ns_ = 0;
    }
    if (stopping_.load()) break;

    auto item = queue_.pop(std::chrono::milliseconds(50));
    if (item && state_.load() == heartbeat_t::STATE_RUNNING && session_.active()) {
      worker_busy_since_ns_ = steady_ns();
      // Behind the camera: this frame is tracked only, so that the queue empties before it must
      // drop frames (fusion_daemon.shed_fusion_queue_share).
      fuse(*item, config_.fusion.shed_fusion(queue_.size()) ? FrameWork::kTrackOnly
                                                             : FrameWork::kTrackAndFuse);
      worker_busy_since_ns_ = 0;
    } else if (item) {
      ++frames_ignored_;  // queued just before a pause or stop
    }

    preview_.tick(state_.load(), session_.active() ? session_.scan_id() : "",
                  session_.reconstructor());
    refresh_sink_counters();
    refresh_graph_counters();
    // Full checkpoints. With the frame log (fusion_daemon.frame_log_interval_s) a crash loses only
    // the frames since its last commit, and these bound what a resume replays; without it, a crash
    // loses the frames since the last committed checkpoint's snapshot.
    if (state_.load() == heartbeat_t::STATE_RUNNING && session_.checkpoint_due()) {
      if (auto st = session_.checkpoint("periodic", progress()); !st.is_ok())
        set_error("checkpoint: " + st.to_string());
    }
  }
  // Shutting down (SIGTERM): a running scan is saved, not lost; if the scan directory cannot take
  // it, the temporary directory gets it rather than nobody.
  if (session_.active()) {
    std::string message;
    if (auto st = stop_scan("sigterm", &message); !st.is_ok()) {
      DF_LOG(Fusion, Error) << st.to_string();
      const std::string rescue =
          (std::filesystem::temp_directory_path() / "depthfuse-rescue").string();
      session_.save_to(rescue);
      DF_LOG(Fusion, Info) << "saving scan " << session_.scan_id() << " to " << rescue
                           << " instead";
      if (auto again = stop_scan("sigterm", &message); !again.is_ok()) {
        DF_LOG(Fusion, Error) << again.to_string();
        set_error(again.to_string());
      }
    }
  }
}

void FusionDaemon::refresh_graph_counters() {
  const FramePath* path = session_.path();
  if (!path) return;
  const LoopClosureStats stats = path->loop_closure_stats();
  graph_keyframes_ = static_cast<int64_t>(path->graph().keyframes().size());
  graph_loops_ = static_cast<int64_t>(path->graph().loops().size());
  graph_corrections_ = static_cast<int64_t>(path->graph().version());
  loop_candidates_ = static_cast<int64_t>(stats.candidates);
  loops_gated_ = static_cast<int64_t>(stats.gated);
  loops_rejected_ = static_cast<int64_t>(stats.rejected);
}

// The sink belongs to the worker; the heartbeat (receive thread) reads a copy of its figures. A
// failure they count comes with its error in the same update: otherwise a heartbeat could count a
// failed background checkpoint, collected by a frame, with no word of it until the next periodic
// call, a whole checkpoint interval later.
void FusionDaemon::refresh_sink_counters() {
  std::vector<std::pair<std::string, double>> counters;
  sink_->add_counters(&counters);
  const Status failed = sink_->take_unreported_failure();
  if (!failed.is_ok()) DF_LOG(Fusion, Warning) << "checkpoint store: " << failed.to_string();
  std::lock_guard<std::mutex> lock(mutex_);
  sink_counters_.swap(counters);
  if (!failed.is_ok()) last_error_ = "checkpoint store: " + failed.to_string();
}

// ---------------------------------------------------------------- heartbeat

void FusionDaemon::publish_heartbeat() {
  heartbeat_t hb = hb_base_.make(state_.load());
  hb.input_rate_hz = in_rate_.rate_hz();
  hb.output_rate_hz = out_rate_.rate_hz();
  hb.frames_in = frames_in_.load();
  hb.frames_out = frames_fused_.load();
  hb.frames_dropped = queue_.dropped();
  hb.frames_lost = counters_.lost.load();
  hb.messages_malformed = counters_.malformed.load();
  hb.messages_bad_version = counters_.bad_version.load();
  hb.messages_foreign = counters_.foreign.load();
  hb.frames_out_of_order = counters_.out_of_order.load();
  hb.queue_depth = static_cast<int32_t>(queue_.size());
  hb.queue_capacity = static_cast<int32_t>(queue_.capacity());
  hb.point_count = point_count_.load();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    hb.scan_id = scan_id_;
    hb.last_error = last_error_;
    hb.last_command_id = ack_.id;
    hb.last_command_result = ack_.result;
    hb.last_command_message = ack_.message;
    daemon::add_counter(&hb, "latency_ms_mean", mean_latency_ms_);
    daemon::add_counter(&hb, "prefilter_ms_mean", mean_prefilter_ms_);
    daemon::add_counter(&hb, "registration_ms_mean", mean_registration_ms_);
    daemon::add_counter(&hb, "fusion_ms_mean", mean_fusion_ms_);
    daemon::add_counter(&hb, "icp_fitness_mean", mean_fitness_);
    daemon::add_counter(&hb, "icp_rmse_mm_mean", mean_rmse_m_ * 1e3);
    // TrackingState of the last frame processed (0 tracked, 1 uncertain, 2 lost), and frames by it.
    daemon::add_counter(&hb, "tracking_state", tracking_state_.load());
    daemon::add_counter(&hb, "color_wrong_size", static_cast<double>(color_wrong_size_.load()));
    daemon::add_counter(&hb, "frames_tracked", static_cast<double>(frames_tracked_.load()));
    daemon::add_counter(&hb, "frames_uncertain", static_cast<double>(frames_uncertain_.load()));
    daemon::add_counter(&hb, "frames_lost_tracking", static_cast<double>(frames_lost_tracking_.load()));
    // Frames whose tracking was lost and that were found among the keyframes (counted as tracked).
    daemon::add_counter(&hb, "relocalisations", static_cast<double>(relocalisations_.load()));
    // Places found for a lost frame that the camera cannot have got to in the time lost.
    daemon::add_counter(&hb, "relocalisations_refused",
                        static_cast<double>(relocalisations_refused_.load()));
    // Places found for a lost frame that another mapped place fits as well (a twin room).
    daemon::add_counter(&hb, "relocalisations_ambiguous",
                        static_cast<double>(relocalisations_ambiguous_.load()));
    daemon::add_counter(&hb, "sequence_restarts", static_cast<double>(counters_.sequence_restarts));
    daemon::add_counter(&hb, "pose_hints_refused", static_cast<double>(counters_.pose_hints_refused));
    for (const auto& [counter, value] : sink_counters_) daemon::add_counter(&hb, counter, value);
    daemon::add_receive_counters(*lcm_, &hb);
  }
  std::vector<std::pair<std::string, double>> preview_counters;
  preview_.add_counters(&preview_counters);
  for (const auto& [counter, value] : preview_counters) daemon::add_counter(&hb, counter, value);
  daemon::add_counter(&hb, "frames_ignored", static_cast<double>(frames_ignored_.load()));
  daemon::add_counter(&hb, "frames_fusion_shed", static_cast<double>(frames_fusion_shed_.load()));
  daemon::add_counter(&hb, "frames_other_serial", static_cast<double>(frames_other_serial_.load()));
  daemon::add_counter(&hb, "frames_registered", static_cast<double>(registered_.load()));
  daemon::add_counter(&hb, "icp_failures", static_cast<double>(icp_failures_.load()));
  daemon::add_counter(&hb, "process_errors", static_cast<double>(process_errors_.load()));
  // The pose graph and its loop closer (the worker's; read here without a lock: figures that may
  // be a frame old).
  daemon::add_counter(&hb, "keyframes", static_cast<double>(graph_keyframes_.load()));
  daemon::add_counter(&hb, "loop_closures", static_cast<double>(graph_loops_.load()));
  daemon::add_counter(&hb, "graph_corrections", static_cast<double>(graph_corrections_.load()));
  daemon::add_counter(&hb, "loop_candidates", static_cast<double>(loop_candidates_.load()));
  daemon::add_counter(&hb, "loops_gated", static_cast<double>(loops_gated_.load()));
  daemon::add_counter(&hb, "loops_rejected", static_cast<double>(loops_rejected_.load()));
  daemon::add_counter(&hb, "last_correction_mm", last_correction_mm_.load());
  // fusion_daemon.memory_budget_mib as split: the per-frame work's parts, and the map's rest (its
  // use: resident_mib).
  daemon::add_counter(&hb, "budget_queue_mib", budget_.queue_mib);
  daemon::add_counter(&hb, "budget_receive_mib", budget_.receive_mib);
  daemon::add_counter(&hb, "budget_fusing_mib", budget_.worker_mib);
  daemon::add_counter(&hb, "budget_frame_log_mib", budget_.frame_log_mib);
  daemon::add_counter(&hb, "budget_map_mib", budget_.map_mib());
  if (auto st = lcm_->publish_message(lcm::kHeartbeatChannel, hb); !st.is_ok())
    set_error(st.message());
}

int FusionDaemon::run(const std::function<bool()>& stop_requested) {
  worker_ = std::thread([this] { worker_loop(); });
  if (!options_.autostart_scan.empty()) {
    command_t cmd;
    cmd.protocol_version = command_t::PROTOCOL_VERSION;
    cmd.command_id = -1;  // never collides with an operator's (positive) id
    cmd.target = options_.name;
    cmd.action = command_t::ACTION_START;
    cmd.argument = options_.autostart_scan;
    cmd.sender = "--autostart";
    std::lock_guard<std::mutex> lock(mutex_);
    commands_.push_back(cmd);
  }
  daemon::notify_ready("listening on " + lcm_->url() + ", checkpoints: " + sink_->describe());
  daemon::WatchdogPetter watchdog;
  const auto hb_period = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(1.0 / config_.fusion.heartbeat_rate_hz));
  auto next_hb = Clock::now();
  int exit_code = 0;
  while (!stop_requested()) {
    auto r = lcm_->handle(20);
    if (!r && !stop_requested()) {
      set_error(r.status().to_string());
      DF_LOG(Fusion, Error) << r.status().to_string();
      exit_code = 1;
      break;
    }
    const auto now = Clock::now();
    if (now >= next_hb) {
      publish_heartbeat();
      const int64_t busy_since = worker_busy_since_ns_.load();
      if (busy_since == 0 || (steady_ns() - busy_since) * 1e-9 < kStuckWorkerS) {
        watchdog.pet();
      } else {
        set_error("the fusion worker has been busy with one frame or command for " +
                  std::to_string(static_cast<int>((steady_ns() - busy_since) * 1e-9)) + " s");
      }
      daemon::notify_status(std::string(daemon::state_name(state_.load())) + ", " +
                            std::to_string(frames_fused_.load()) + " frames fused, " +
                            std::to_string(point_count_.load()) + " points");
      next_hb += hb_period;
      if (next_hb < now) next_hb = now + hb_period;
    }
  }
  daemon::notify_stopping();
  stopping_ = true;
  queue_.wake();
  if (worker_.joinable()) worker_.join();
  state_ = heartbeat_t::STATE_STOPPING;
  publish_heartbeat();
  return exit_code;
}

}  // namespace depthfuse::fusiond
