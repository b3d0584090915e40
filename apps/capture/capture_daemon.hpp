// The capture daemon: a FrameSource's frames out on LCM, with its own sequence numbers, colour
// before depth, and a heartbeat once a second.
//  - the capture thread (run()) opens the source, waiting for a live device that is not there
//    yet, then reads, paces (Pacer) and publishes frames until it is stopped, the source ends
//    (unless it lingers) or fails;
//  - the service thread receives LCM: the operator's pause/resume/stop/start addressed to this
//    daemon, answered in the heartbeat it publishes at once and every second; it also feeds the
//    systemd watchdog, unless the source has been stuck inside next() for too long.
#pragma once

#include <atomic>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "capture_options.hpp"
#include "depthfuse/app_config.hpp"
#include "depthfuse/color_frame_t.hpp"
#include "depthfuse/daemon/heartbeat.hpp"
#include "depthfuse/daemon/rate_meter.hpp"
#include "depthfuse/daemon/signals.hpp"
#include "depthfuse/depth_frame_t.hpp"
#include "depthfuse/frame_source.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/transport.hpp"

namespace depthfuse::capture {

class CaptureDaemon {
 public:
  CaptureDaemon(const AppConfig& config, CaptureOptions options,
                std::unique_ptr<lcm::LcmTransport> lcm);
  ~CaptureDaemon();

  // Runs until `shutdown` is requested or the source is done; the exit code: 0, or 1 when the
  // source could not be opened or failed.
  int run(daemon::ShutdownSignal& shutdown);

 private:
  // Capture thread.
  // Null when it cannot be opened (*exit_code = 1) or a stop was requested while waiting.
  std::unique_ptr<FrameSource> open_source(const daemon::ShutdownSignal& shutdown, int* exit_code);
  int publish_frames(FrameSource& source, const daemon::ShutdownSignal& shutdown);
  void publish(Frame& frame);
  // Service thread.
  void service_loop(const daemon::ShutdownSignal& shutdown);
  void on_command(const uint8_t* data, size_t size);
  // Either thread.
  depthfuse::heartbeat_t publish_heartbeat();
  void set_error(const std::string& error);

  AppConfig config_;
  CaptureOptions options_;
  std::unique_ptr<lcm::LcmTransport> lcm_;
  daemon::HeartbeatBase hb_base_;
  daemon::ShutdownSignal* shutdown_ = nullptr;  // run()'s
  std::thread service_;

  // Shared.
  std::atomic<int8_t> state_;
  std::atomic<bool> publishing_{true};  // false after pause/stop
  std::atomic<int64_t> frames_in_{0}, frames_out_{0}, source_errors_{0};
  std::atomic<int64_t> bytes_out_{0}, encode_us_{0};
  // When the capture thread entered source->next() (steady clock, ns), 0 when not inside: a
  // driver stuck there for longer than kStuckSourceS stops the systemd watchdog, so systemd
  // restarts us.
  std::atomic<int64_t> in_source_since_ns_{0};
  // The source once open, for its device status; it outlives the service thread.
  std::atomic<const FrameSource*> source_{nullptr};
  lcm::ReceiveCounters command_counters_;
  daemon::RateMeter read_rate_, publish_rate_;
  std::mutex mutex_;  // guards the fields below
  std::string last_error_;
  int64_t last_command_id_ = 0;
  int8_t last_command_result_;
  std::string last_command_message_;
  // A live device's status until its source is open (see device_status_before_open).
  std::optional<DeviceStatus> device_before_open_;

  // Capture thread only.
  bool told_ready_ = false;  // READY=1 went to systemd
  uint32_t sequence_ = 0;
  depthfuse::depth_frame_t depth_msg_;
  depthfuse::color_frame_t color_msg_;
};

}  // namespace depthfuse::capture
