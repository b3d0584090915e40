// The Kinect V2 source's state as the FrameSource::device_status every device source gives, for
// the heartbeat of the daemon that reads it.
#include <string>

#include "depthfuse/kinect2/kinect2_source.hpp"

namespace depthfuse::kinect2 {
namespace {

DeviceStatus::Reading reading(Kinect2State state) {
  switch (state) {
    case Kinect2State::kConnected: return DeviceStatus::Reading::kStreaming;
    case Kinect2State::kWaitingForDevice:
    case Kinect2State::kOpening: return DeviceStatus::Reading::kWaiting;
    case Kinect2State::kStalled:
    case Kinect2State::kRecovering: return DeviceStatus::Reading::kFailing;
  }
  return DeviceStatus::Reading::kFailing;
}

// "kinect2_state_waiting_for_device", "kinect2_state_connected", ...: the one counter with value 1
// that names the state, for readers that show only keys and values.
std::string state_counter_key(Kinect2State state) {
  std::string key = std::string("kinect2_state_") + to_string(state);
  for (char& c : key)
    if (c == ' ') c = '_';
  return key;
}

}  // namespace

DeviceStatus to_device_status(const Kinect2Status& status) {
  DeviceStatus device;
  device.reading = reading(status.state);
  device.summary = status.summary();
  device.counters = {
      {"kinect2_state", static_cast<double>(static_cast<int>(status.state))},
      {state_counter_key(status.state), 1.0},
      {"kinect2_frames", static_cast<double>(status.frames)},
      {"kinect2_stalls", static_cast<double>(status.stalls)},
      {"kinect2_usb_resets", static_cast<double>(status.usb_resets)},
      {"kinect2_reconnects", static_cast<double>(status.reconnects)},
      {"kinect2_usb_hotplug", status.usb_hotplug ? 1.0 : 0.0},
      {"kinect2_dropped_packets", static_cast<double>(status.dropped_packets)},
  };
  return device;
}

std::optional<DeviceStatus> Kinect2Source::device_status() const {
  return to_device_status(status());
}

DeviceStatus kinect2_status_before_open(const std::string& serial_or_empty, const AppConfig& config,
                                        const std::string& detail) {
  Kinect2Status status;
  status.serial = serial_or_empty;
  status.pipeline = config.capture.kinect2_pipeline;
  status.detail = detail.empty() ? "opening the kinect2 source" : detail;
  return to_device_status(status);
}

}  // namespace depthfuse::kinect2
