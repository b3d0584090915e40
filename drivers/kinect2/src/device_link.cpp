#include "depthfuse/kinect2/device_link.hpp"

#include <cstdio>

namespace depthfuse::kinect2 {

const char* to_string(Kinect2State state) {
  switch (state) {
    case Kinect2State::kWaitingForDevice: return "waiting for device";
    case Kinect2State::kOpening: return "opening";
    case Kinect2State::kConnected: return "connected";
    case Kinect2State::kStalled: return "stalled";
    case Kinect2State::kRecovering: return "recovering";
  }
  return "unknown";
}


const char* to_string(LinkAction action) {
  switch (action) {
    case LinkAction::kNone: return "none";
    case LinkAction::kOpen: return "open";
    case LinkAction::kClose: return "close";
    case LinkAction::kResetUsb: return "reset USB";
  }
  return "unknown";
}

namespace {

DeviceLink::Clock::duration seconds(double s) {
  return std::chrono::duration_cast<DeviceLink::Clock::duration>(std::chrono::duration<double>(s));
}

double seconds_between(DeviceLink::TimePoint from, DeviceLink::TimePoint to) {
  return std::chrono::duration<double>(to - from).count();
}

std::string format_s(double s) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.1f s", s);
  return text;
}

}  // namespace

DeviceLink::DeviceLink(const DeviceLinkConfig& config) : config_(config) {}

LinkAction DeviceLink::request(LinkAction action) {
  pending_ = action;
  return action;
}

LinkAction DeviceLink::go_waiting(const std::string& why) {
  state_ = Kinect2State::kWaitingForDevice;
  detail_ = why;
  open_failures_ = 0;
  got_frame_ = false;
  // The device is gone: whatever handle we hold is dead and must be released.
  if (open_ && pending_ != LinkAction::kClose) return request(LinkAction::kClose);
  return LinkAction::kNone;
}

LinkAction DeviceLink::on_presence(bool present, TimePoint now) {
  const bool was_present = present_;
  present_ = present;
  if (!present) {
    if (state_ == Kinect2State::kWaitingForDevice && !open_) return LinkAction::kNone;
    return go_waiting(was_present ? "Kinect V2 unplugged" : "no Kinect V2 on USB");
  }
  if (state_ == Kinect2State::kWaitingForDevice && pending_ == LinkAction::kNone && !open_) {
    state_ = Kinect2State::kOpening;
    detail_ = "Kinect V2 detected, opening it";
    open_failures_ = 0;
    retry_at_ = now;
    return request(LinkAction::kOpen);
  }
  return LinkAction::kNone;
}

LinkAction DeviceLink::on_opened(TimePoint now) {
  pending_ = LinkAction::kNone;
  open_ = true;
  if (ever_opened_) ++reconnects_;
  ever_opened_ = true;
  open_failures_ = 0;
  if (!present_) return go_waiting("Kinect V2 unplugged while it was being opened");
  state_ = Kinect2State::kConnected;
  detail_ = "streaming, waiting for the first frame";
  opened_at_ = now;
  got_frame_ = false;
  return LinkAction::kNone;
}

LinkAction DeviceLink::on_open_failed(const std::string& why, TimePoint now) {
  pending_ = LinkAction::kNone;
  ++open_failures_;
  if (!present_) return go_waiting(why);
  if (static_cast<int>(open_failures_) >= config_.open_failures_before_reset) {
    state_ = Kinect2State::kRecovering;
    detail_ = std::to_string(open_failures_) + " failed opens (" + why + "); resetting USB";
    return request(LinkAction::kResetUsb);
  }
  state_ = Kinect2State::kOpening;
  detail_ = "open failed (" + why + "); retrying in " + format_s(config_.open_retry_interval_s);
  retry_at_ = now + seconds(config_.open_retry_interval_s);
  return LinkAction::kNone;
}

LinkAction DeviceLink::on_frame(TimePoint now) {
  if (state_ != Kinect2State::kConnected) return LinkAction::kNone;  // a straggler: ignore
  ++frames_;
  got_frame_ = true;
  last_frame_at_ = now;
  detail_ = "streaming";
  return LinkAction::kNone;
}

LinkAction DeviceLink::on_closed(TimePoint) {
  pending_ = LinkAction::kNone;
  open_ = false;
  if (state_ == Kinect2State::kStalled) {
    state_ = Kinect2State::kRecovering;
    detail_ += "; resetting USB";
    return request(LinkAction::kResetUsb);
  }
  return LinkAction::kNone;
}

LinkAction DeviceLink::on_reset(bool ok, const std::string& why, TimePoint now) {
  pending_ = LinkAction::kNone;
  if (ok) ++usb_resets_;
  open_failures_ = 0;
  if (!present_) return go_waiting("no Kinect V2 on USB after the USB reset");
  // Reopen after a pause: a reset device drops off the bus and enumerates again.
  state_ = Kinect2State::kOpening;
  detail_ = ok ? std::string("USB reset done; reopening")
               : "USB reset failed (" + why + "); reopening anyway";
  retry_at_ = now + seconds(config_.open_retry_interval_s);
  return LinkAction::kNone;
}

LinkAction DeviceLink::on_tick(TimePoint now) {
  if (pending_ != LinkAction::kNone) return LinkAction::kNone;
  switch (state_) {
    case Kinect2State::kConnected: {
      const TimePoint since = got_frame_ ? last_frame_at_ : opened_at_;
      const double limit = got_frame_ ? config_.stall_timeout_s : config_.first_frame_timeout_s;
      const double quiet = seconds_between(since, now);
      if (quiet <= limit) return LinkAction::kNone;
      state_ = Kinect2State::kStalled;
      ++stalls_;
      detail_ = std::string(got_frame_ ? "no frame for " : "no first frame after ") +
                format_s(quiet) + " (limit " + format_s(limit) + ")";
      return request(LinkAction::kClose);
    }
    case Kinect2State::kOpening:
      if (present_ && !open_ && now >= retry_at_) return request(LinkAction::kOpen);
      return LinkAction::kNone;
    case Kinect2State::kWaitingForDevice:
    case Kinect2State::kStalled:
    case Kinect2State::kRecovering:
      return LinkAction::kNone;
  }
  return LinkAction::kNone;
}

DeviceLink::TimePoint DeviceLink::next_deadline() const {
  if (pending_ != LinkAction::kNone) return TimePoint::max();
  if (state_ == Kinect2State::kConnected) {
    return got_frame_ ? last_frame_at_ + seconds(config_.stall_timeout_s)
                      : opened_at_ + seconds(config_.first_frame_timeout_s);
  }
  if (state_ == Kinect2State::kOpening && present_ && !open_) return retry_at_;
  return TimePoint::max();
}

}  // namespace depthfuse::kinect2
