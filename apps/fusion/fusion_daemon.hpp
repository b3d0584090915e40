// The fusion daemon: LCM depth frames in, refined poses out, one scan at a time.
//  - the receive thread (run()) decodes and checks messages, counts what it cannot use, and pushes
//    frames into a bounded queue that drops the oldest frame when fusion falls behind; it never
//    waits on fusion work;
//  - the worker thread runs the scan (ScanSession: each frame's path, predict -> prepare -> process
//    -> record, and the periodic checkpoint), publishes each frame's pose, and carries out the
//    operator's commands between frames.
// The heartbeat is published by either.
#pragma once

#include <atomic>
#include <chrono>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "checkpoint_sink.hpp"
#include "depthfuse/app_config.hpp"
#include "depthfuse/command_t.hpp"
#include "depthfuse/daemon/bounded_queue.hpp"
#include "depthfuse/daemon/heartbeat.hpp"
#include "depthfuse/daemon/rate_meter.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/frame_codec.hpp"
#include "depthfuse/lcm/transport.hpp"
#include "depthfuse/pipeline.hpp"
#include "map_preview.hpp"
#include "memory_budget.hpp"
#include "scan_session.hpp"

namespace depthfuse::fusiond {

struct DaemonOptions {
  std::string name = "fusion";    // heartbeat name and command target
  std::string autostart_scan;     // non-empty: start this scan at once ("-" = a generated name)
};

class FusionDaemon {
 public:
  FusionDaemon(const AppConfig& config, const DaemonOptions& options,
               std::unique_ptr<lcm::LcmTransport> lcm, std::unique_ptr<CheckpointSink> sink);
  ~FusionDaemon();

  // Receives until stop_requested() turns true; then ends the worker (saving an open scan).
  int run(const std::function<bool()>& stop_requested);

 private:
  struct QueuedFrame {
    Frame frame;
    int64_t publish_utime = 0;  // the capture's publish time (latency)
  };
  struct Ack {
    int64_t id = 0;
    int8_t result = 0;
    std::string message;
  };

  void on_depth(const uint8_t* data, size_t size);
  void on_color(const uint8_t* data, size_t size);
  // Whether a frame of this sensor serial is fused (fusion_daemon.capture_serial).
  bool follows(const std::string& sensor_serial) const {
    return config_.fusion.capture_serial.empty() || sensor_serial == config_.fusion.capture_serial;
  }
  void on_command(const uint8_t* data, size_t size);
  void worker_loop();
  void execute(const depthfuse::command_t& cmd);
  Status start_scan(const std::string& requested_name, std::string* message);
  Status stop_scan(const std::string& reason, std::string* message);
  void fuse(QueuedFrame& item, FrameWork work);
  void publish_frame(const QueuedFrame& item, const FrameReport& report);
  void publish_correction(const AppliedCorrection& correction);
  // The pose graph's figures for the heartbeat.
  void refresh_graph_counters();
  // The daemon's counters, for checkpoints.
  FusionProgress progress() const;
  void count_tracking(const FrameReport& report);
  void publish_heartbeat();
  void refresh_sink_counters();
  void set_error(const std::string& e);

  AppConfig config_;
  MemoryBudget budget_;            // reported in the heartbeat
  lcm::FrameLimits frame_limits_;  // what on_depth and on_color take from the bus
  DaemonOptions options_;
  std::unique_ptr<lcm::LcmTransport> lcm_;
  std::unique_ptr<CheckpointSink> sink_;
  daemon::HeartbeatBase hb_base_;
  daemon::BoundedQueue<QueuedFrame> queue_;
  MapPreview preview_;  // viewers' map deltas (worker), their snapshot requests (receive thread)

  // Receive thread only.
  std::map<std::string, lcm::SequenceTracker> sequences_;  // per publisher (source|serial)
  std::map<int64_t, ColorImage> pending_color_;  // by sequence, the last few

  // Shared.
  std::atomic<int8_t> state_;
  std::atomic<bool> stopping_{false};
  lcm::ReceiveCounters counters_;             // all our channels together
  std::atomic<int64_t> frames_in_{0}, frames_fused_{0}, frames_ignored_{0};
  // Frames tracked but not fused because the queue was filling (shed_fusion_queue_share).
  std::atomic<int64_t> frames_fusion_shed_{0};
  std::atomic<int64_t> frames_other_serial_{0};  // not fusion_daemon.capture_serial's
  std::atomic<int64_t> process_errors_{0}, icp_failures_{0}, registered_{0};
  // Frames by the tracking state the worker gave them, and the last one's state.
  std::atomic<int64_t> frames_tracked_{0}, frames_uncertain_{0}, frames_lost_tracking_{0};
  std::atomic<int64_t> relocalisations_{0};
  std::atomic<int64_t> relocalisations_refused_{0}, relocalisations_ambiguous_{0};
  std::atomic<int64_t> graph_keyframes_{0}, graph_loops_{0}, graph_corrections_{0};
  std::atomic<int64_t> loop_candidates_{0}, loops_gated_{0}, loops_rejected_{0};
  std::atomic<double> last_correction_mm_{0.0};
  std::atomic<int> tracking_state_{0};
  std::atomic<int64_t> color_wrong_size_{0};  // colour frames not the size of their depth frame
  int64_t frames_lost_in_a_row_ = 0;  // worker thread only
  std::atomic<int64_t> point_count_{0};
  // When the worker started its current frame or command (steady clock, ns), 0 when waiting: a
  // worker busy for longer than kStuckWorkerS stops the systemd watchdog.
  std::atomic<int64_t> worker_busy_since_ns_{0};
  daemon::RateMeter in_rate_, out_rate_;
  std::mutex mutex_;                            // guards the fields below
  std::string scan_id_, last_error_;
  Ack ack_;
  std::deque<depthfuse::command_t> commands_;
  std::deque<int64_t> recent_command_ids_;      // queued or carried out, newest last
  std::vector<std::pair<std::string, double>> sink_counters_;  // the checkpoint store's figures
  double mean_latency_ms_ = 0, mean_prefilter_ms_ = 0, mean_registration_ms_ = 0,
         mean_fusion_ms_ = 0, mean_fitness_ = 0, mean_rmse_m_ = 0;

  // Worker only.
  ScanSession session_;
  std::thread worker_;
};

}  // namespace depthfuse::fusiond
