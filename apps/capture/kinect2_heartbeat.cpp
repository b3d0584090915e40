#include "kinect2_heartbeat.hpp"

#include <string>

#include "depthfuse/daemon/heartbeat.hpp"

namespace depthfuse::capture {

int8_t heartbeat_state(Kinect2State state) {
  switch (state) {
    case Kinect2State::kConnected: return heartbeat_t::STATE_RUNNING;
    case Kinect2State::kWaitingForDevice:
    case Kinect2State::kOpening: return heartbeat_t::STATE_IDLE;
    case Kinect2State::kStalled:
    case Kinect2State::kRecovering: return heartbeat_t::STATE_ERROR;
  }
  return heartbeat_t::STATE_ERROR;
}

double state_code(Kinect2State state) { return static_cast<double>(static_cast<int>(state)); }

std::string state_counter_key(Kinect2State state) {
  std::string key = std::string("kinect2_state_") + to_string(state);
  for (char& c : key)
    if (c == ' ') c = '_';
  return key;
}

void annotate_heartbeat(const Kinect2Status& status, depthfuse::heartbeat_t* hb) {
  if (hb->state == heartbeat_t::STATE_RUNNING || hb->state == heartbeat_t::STATE_IDLE) {
    hb->state = heartbeat_state(status.state);
    if (status.state != Kinect2State::kConnected) hb->last_error = status.summary();
  }
  daemon::add_counter(hb, "kinect2_state", state_code(status.state));
  daemon::add_counter(hb, state_counter_key(status.state), 1.0);
  daemon::add_counter(hb, "kinect2_frames", static_cast<double>(status.frames));
  daemon::add_counter(hb, "kinect2_stalls", static_cast<double>(status.stalls));
  daemon::add_counter(hb, "kinect2_usb_resets", static_cast<double>(status.usb_resets));
  daemon::add_counter(hb, "kinect2_reconnects", static_cast<double>(status.reconnects));
  daemon::add_counter(hb, "kinect2_usb_hotplug", status.usb_hotplug ? 1.0 : 0.0);
}

}  // namespace depthfuse::capture
