// The life cycle of the link to one Kinect V2, as a pure state machine: events go in (device
// present or gone, open succeeded or failed, a frame arrived, the clock moved on), the action its
// owner must take comes out (open, close, USB reset). No I/O and no clock of its own, so that every
// path (unplug, replug, stall, failed reopen) can be driven in a test.
//
//   waiting for device --present--> opening --opened--> connected --frame--> connected
//        ^                            ^  |                  |
//        |  (gone, from any state)    |  | N failed opens   | no frame for stall_timeout_s
//        |                            |  v                  v
//        +------------------------- recovering <--closed-- stalled
//                                 (USB reset, then reopen)
#pragma once

#include <chrono>
#include <cstdint>
#include <string>

namespace depthfuse::kinect2 {

// What the capture daemon reports in its heartbeat.
enum class Kinect2State {
  kWaitingForDevice,  // no Kinect V2 on USB (or not the one with the configured serial)
  kOpening,           // present; opening it, or waiting to retry a failed open
  kConnected,         // streaming
  kStalled,           // streaming stopped delivering frames; about to close it
  kRecovering,        // closed; resetting the USB device before reopening it
};

// "waiting for device", "opening", "connected", "stalled", "recovering"
const char* to_string(Kinect2State state);


enum class LinkAction {
  kNone,
  kOpen,      // open and start the device, then report on_opened or on_open_failed
  kClose,     // stop and close the device, then report on_closed
  kResetUsb,  // reset the device's USB port, then report on_reset
};

const char* to_string(LinkAction action);

struct DeviceLinkConfig {
  double stall_timeout_s = 2.0;        // connected and no frame for this long = stalled
  double first_frame_timeout_s = 10.0; // after opening, the first frame may take this long
  double open_retry_interval_s = 1.0;  // a present device that failed to open is retried this often
  int open_failures_before_reset = 3;  // consecutive failed opens, then a USB reset
};

class DeviceLink {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;

  explicit DeviceLink(const DeviceLinkConfig& config = {});

  // Events. Each returns what the owner must do now; kNone means nothing. An action other than
  // kNone must be carried out and its outcome reported (on_opened/on_open_failed, on_closed,
  // on_reset) before the next action is handed out.
  LinkAction on_presence(bool present, TimePoint now);
  LinkAction on_opened(TimePoint now);
  LinkAction on_open_failed(const std::string& why, TimePoint now);
  LinkAction on_frame(TimePoint now);
  LinkAction on_closed(TimePoint now);
  LinkAction on_reset(bool ok, const std::string& why, TimePoint now);
  // The timers: stall detection and open retries.
  LinkAction on_tick(TimePoint now);

  Kinect2State state() const { return state_; }
  // Why the link is in its state, for status lines: "no Kinect V2 on USB", "no frame for 2.3 s", ...
  const std::string& detail() const { return detail_; }
  bool device_present() const { return present_; }
  bool device_open() const { return open_; }
  LinkAction pending() const { return pending_; }
  // When on_tick will next have something to do; TimePoint::max() when no timer runs.
  TimePoint next_deadline() const;

  uint64_t frames() const { return frames_; }
  uint32_t stalls() const { return stalls_; }
  uint32_t usb_resets() const { return usb_resets_; }
  uint32_t reconnects() const { return reconnects_; }  // successful opens after the first
  uint32_t open_failures() const { return open_failures_; }  // consecutive

 private:
  LinkAction request(LinkAction action);
  LinkAction go_waiting(const std::string& why);

  DeviceLinkConfig config_;
  Kinect2State state_ = Kinect2State::kWaitingForDevice;
  std::string detail_ = "no Kinect V2 on USB";
  LinkAction pending_ = LinkAction::kNone;
  bool present_ = false;
  bool open_ = false;
  bool ever_opened_ = false;
  bool got_frame_ = false;
  TimePoint opened_at_{};
  TimePoint last_frame_at_{};
  TimePoint retry_at_{};
  uint64_t frames_ = 0;
  uint32_t stalls_ = 0;
  uint32_t usb_resets_ = 0;
  uint32_t reconnects_ = 0;
  uint32_t open_failures_ = 0;
};

}  // namespace depthfuse::kinect2
