// The capture daemon (see capture_daemon.hpp for its two threads).
#include "capture_daemon.hpp"

#include <chrono>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/command_t.hpp"
#include "depthfuse/daemon/systemd_notify.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/frame_codec.hpp"
#include "depthfuse/source_factory.hpp"

DF_LOG_CATEGORY(Capture)

namespace depthfuse::capture {
namespace {

using depthfuse::command_t;
using depthfuse::heartbeat_t;
using Clock = std::chrono::steady_clock;

constexpr double kStuckSourceS = 10.0;
// A source whose next() said kUnavailable is asked again after at least this long (counted from
// the call: a driver that already waited inside next(), like the Kinect's, is asked again at once).
constexpr double kUnavailableRetryS = 0.5;
// A device source that could not be opened because its bus is not accessible is tried again this
// often.
constexpr double kOpenRetryS = 2.0;

}  // namespace

CaptureDaemon::CaptureDaemon(const AppConfig& config, CaptureOptions options,
                             std::unique_ptr<lcm::LcmTransport> lcm)
    : config_(config),
      options_(std::move(options)),
      lcm_(std::move(lcm)),
      hb_base_(options_.name),
      state_(heartbeat_t::STATE_STARTING),
      last_command_result_(heartbeat_t::COMMAND_RESULT_NONE),
      device_before_open_(device_status_before_open(options_.source_spec, config_, "")) {
  lcm_->subscribe(lcm::kCommandChannel, [this](const std::string&, const uint8_t* data,
                                                 size_t size, int64_t) { on_command(data, size); });
}

CaptureDaemon::~CaptureDaemon() {
  if (service_.joinable()) {  // run() left by an exception
    shutdown_->request_stop();
    service_.join();
  }
}

int CaptureDaemon::run(daemon::ShutdownSignal& shutdown) {
  shutdown_ = &shutdown;
  service_ = std::thread([this, &shutdown] { service_loop(shutdown); });
  int exit_code = 0;
  auto source = open_source(shutdown, &exit_code);
  if (source) {
    source_ = source.get();
    exit_code = publish_frames(*source, shutdown);
    state_ = heartbeat_t::STATE_STOPPING;
  } else {  // a bad source, or stopped while waiting for one
    state_ = exit_code == 0 ? heartbeat_t::STATE_STOPPING : heartbeat_t::STATE_ERROR;
  }
  daemon::notify_stopping();
  publish_heartbeat();
  shutdown.request_stop();
  service_.join();
  if (source) {
    DF_LOG(Capture, Info) << "published " << frames_out_.load() << " frames, exiting";
  }
  return exit_code;
}

std::unique_ptr<FrameSource> CaptureDaemon::open_source(const daemon::ShutdownSignal& shutdown,
                                                        int* exit_code) {
  // A device whose bus cannot be accessed (yet) is waited for like an absent one.
  std::string open_error_logged;
  while (!shutdown.stop_requested()) {
    auto opened = open_frame_source(options_.source_spec, config_);
    if (opened) {
      if (!open_error_logged.empty()) set_error("");
      return std::move(opened).value();
    }
    const std::string why =
        "cannot open source '" + options_.source_spec + "': " + opened.status().to_string();
    if (!device_before_open_ || opened.status().code() != StatusCode::kUnavailable) {
      DF_LOG(Capture, Error) << why;
      set_error(why);
      *exit_code = 1;
      return nullptr;
    }
    if (why != open_error_logged) {
      DF_LOG(Capture, Warning) << why << "; trying again every " << kOpenRetryS << " s";
      open_error_logged = why;
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      last_error_ = why;
      device_before_open_ =
          device_status_before_open(options_.source_spec, config_, opened.status().message());
    }
    state_ = heartbeat_t::STATE_IDLE;
    if (!told_ready_) {
      daemon::notify_ready("waiting for " + options_.source_spec);
      told_ready_ = true;
    }
    shutdown.sleep_for(kOpenRetryS);
  }
  return nullptr;
}

int CaptureDaemon::publish_frames(FrameSource& source, const daemon::ShutdownSignal& shutdown) {
  Pacer pacer(options_.rate, source, config_.capture.rate_hz);
  // A device's own status goes into the heartbeat (state, reason, counters): waiting for a
  // device is not a source error. Any other live source that is unavailable is reported as one.
  const bool reports_device_status = source.device_status().has_value();
  DF_LOG(Capture, Info) << source.describe() << " -> " << lcm_->url() << " (" << pacer.describe()
                        << ")";
  state_ = heartbeat_t::STATE_RUNNING;
  if (told_ready_)
    daemon::notify_status("publishing " + source.describe());
  else
    daemon::notify_ready("publishing " + source.describe());

  while (!shutdown.stop_requested()) {
    if (!publishing_.load()) {
      state_ = heartbeat_t::STATE_PAUSED;
      shutdown.sleep_for(0.05);
      pacer.resume();
      continue;
    }
    state_ = heartbeat_t::STATE_RUNNING;
    const int64_t asked_ns = steady_ns();
    in_source_since_ns_ = asked_ns;
    auto frame_r = source.next();
    in_source_since_ns_ = 0;
    if (!frame_r) {
      const auto code = frame_r.status().code();
      if (code == StatusCode::kEndOfStream) {
        if (options_.loop && source.rewind().is_ok()) {
          pacer.rewound();
          continue;
        }
        DF_LOG(Capture, Info) << source.describe() << " ended after " << frames_out_.load()
                              << " frames";
        state_ = heartbeat_t::STATE_FINISHED;
        if (options_.linger) {
          while (!shutdown.sleep_for(0.2)) {
          }
        }
        return 0;
      }
      if (code == StatusCode::kUnavailable) {  // a live device is gone for now: wait
        if (!reports_device_status) {
          ++source_errors_;
          state_ = heartbeat_t::STATE_ERROR;
          set_error(frame_r.status().to_string());
        }
        const double waited_s = (steady_ns() - asked_ns) * 1e-9;
        if (waited_s < kUnavailableRetryS) shutdown.sleep_for(kUnavailableRetryS - waited_s);
        continue;
      }
      ++source_errors_;
      set_error(frame_r.status().to_string());
      DF_LOG(Capture, Error) << frame_r.status().to_string();
      state_ = heartbeat_t::STATE_ERROR;
      return 1;
    }
    Frame frame = std::move(frame_r).value();
    ++frames_in_;
    read_rate_.add();
    // Pace before publishing, so the publish time is the frame's due time.
    if (pacer.wait_for_turn(source, frame, shutdown)) break;
    publish(frame);
  }
  return 0;
}

void CaptureDaemon::publish(Frame& frame) {
  // Our own sequence numbers: receivers count gaps per publisher, whatever the source numbers.
  frame.sequence = sequence_++;
  const auto t0 = Clock::now();
  int64_t bytes = 0;
  if (options_.send_color && !frame.color.empty()) {
    // Colour first: the fusion daemon pairs it with the depth frame that follows.
    auto st = lcm::encode_color_frame(frame, options_.color, &color_msg_);
    if (st.is_ok()) {
      st = lcm_->publish_message(lcm::kColorChannel, color_msg_);
      bytes += color_msg_.getEncodedSize();
    }
    if (!st.is_ok()) set_error("colour: " + st.to_string());
  }
  auto st = lcm::encode_depth_frame(frame, options_.depth, &depth_msg_);
  if (st.is_ok()) {
    depth_msg_.publish_utime = now_utime();
    depth_msg_.source = options_.source_spec;
    st = lcm_->publish_message(lcm::kDepthChannel, depth_msg_);
    bytes += depth_msg_.getEncodedSize();
  }
  if (!st.is_ok()) {
    set_error("depth frame " + std::to_string(frame.sequence) + ": " + st.to_string());
    return;
  }
  encode_us_ += std::chrono::duration_cast<std::chrono::microseconds>(Clock::now() - t0).count();
  bytes_out_ += bytes;
  ++frames_out_;
  publish_rate_.add();
}

void CaptureDaemon::service_loop(const daemon::ShutdownSignal& shutdown) {
  auto next_hb = Clock::now();
  daemon::WatchdogPetter watchdog;
  while (!shutdown.stop_requested()) {
    auto r = lcm_->handle(50);
    if (!r) set_error(r.status().message());
    if (Clock::now() < next_hb) continue;
    const heartbeat_t hb = publish_heartbeat();
    next_hb += std::chrono::seconds(1);
    if (next_hb < Clock::now()) next_hb = Clock::now() + std::chrono::seconds(1);
    const int64_t since = in_source_since_ns_.load();
    if (since == 0 || (steady_ns() - since) * 1e-9 < kStuckSourceS) {
      watchdog.pet();
    } else {
      std::lock_guard<std::mutex> lock(mutex_);
      last_error_ = "the source has not returned a frame for " +
                    std::to_string(static_cast<int>((steady_ns() - since) * 1e-9)) + " s";
      state_ = heartbeat_t::STATE_ERROR;
    }
    daemon::notify_status(std::string(daemon::state_name(hb.state)) + ", " +
                          std::to_string(hb.frames_out) + " frames published" +
                          (hb.last_error.empty() ? std::string() : "; " + hb.last_error));
  }
}

void CaptureDaemon::on_command(const uint8_t* data, size_t size) {
  command_t cmd;
  const auto r = lcm::decode_message(data, size, &cmd);
  command_counters_.count(r);
  if (r != lcm::DecodeResult::kOk) return;
  if (!cmd.target.empty() && cmd.target != options_.name) return;
  std::string message;
  int8_t result = heartbeat_t::COMMAND_RESULT_OK;
  switch (cmd.action) {
    case command_t::ACTION_PAUSE:
    case command_t::ACTION_STOP:
      publishing_ = false;
      message = "publishing paused";
      break;
    case command_t::ACTION_RESUME:
    case command_t::ACTION_START:
      publishing_ = true;
      message = "publishing";
      break;
    default:
      // new scan / checkpoint are the fusion daemon's; only reject when addressed to us.
      if (cmd.target.empty()) return;
      result = heartbeat_t::COMMAND_RESULT_REJECTED;
      message = "capture does not handle this command";
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    last_command_id_ = cmd.command_id;
    last_command_result_ = result;
    last_command_message_ = message;
  }
  if (cmd.target == options_.name) publish_heartbeat();  // the acknowledgement
}

heartbeat_t CaptureDaemon::publish_heartbeat() {
  heartbeat_t hb = hb_base_.make(state_.load());
  hb.input_rate_hz = read_rate_.rate_hz();
  hb.output_rate_hz = publish_rate_.rate_hz();
  hb.frames_in = frames_in_.load();
  hb.frames_out = frames_out_.load();
  hb.messages_malformed = command_counters_.malformed.load();
  hb.messages_bad_version = command_counters_.bad_version.load();
  hb.messages_foreign = command_counters_.foreign.load();
  std::optional<DeviceStatus> device;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    hb.last_error = last_error_;
    hb.last_command_id = last_command_id_;
    hb.last_command_result = last_command_result_;
    hb.last_command_message = last_command_message_;
    if (!source_.load()) device = device_before_open_;
  }
  const double out = static_cast<double>(std::max<int64_t>(1, hb.frames_out));
  daemon::add_counter(&hb, "source_errors", static_cast<double>(source_errors_.load()));
  daemon::add_counter(&hb, "bytes_per_frame", static_cast<double>(bytes_out_.load()) / out);
  daemon::add_counter(&hb, "encode_publish_ms_mean", encode_us_.load() * 1e-3 / out);
  if (const FrameSource* source = source_.load()) device = source->device_status();  // not under mutex_
  if (device) daemon::add_device_status(*device, &hb);
  daemon::add_receive_counters(*lcm_, &hb);
  (void)lcm_->publish_message(lcm::kHeartbeatChannel, hb);
  return hb;
}

void CaptureDaemon::set_error(const std::string& error) {
  std::lock_guard<std::mutex> lock(mutex_);
  last_error_ = error;
}

}  // namespace depthfuse::capture
