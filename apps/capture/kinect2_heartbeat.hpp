// What a Kinect V2 source adds to the capture daemon's heartbeat: the device state (waiting for
// device / opening / connected / stalled / recovering) and the driver's counters. Compiled only
// where the kinect2 driver is built (DEPTHFUSE_CAPTURE_HAS_KINECT2).
#pragma once

#include <cstdint>
#include <string>

#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/kinect2/kinect2_source.hpp"

namespace depthfuse::capture {

// The heartbeat state of a capture daemon that is trying to read from a Kinect in `state`:
// running when connected, idle while there is no device to read (waiting for one, opening it),
// error while a stalled device is being reset.
int8_t heartbeat_state(Kinect2State state);

// The value of the "kinect2_state" counter: the position of `state` in Kinect2State
// (0 waiting for device, 1 opening, 2 connected, 3 stalled, 4 recovering).
double state_code(Kinect2State state);

// "kinect2_state_waiting_for_device", "kinect2_state_connected", ...: the one counter with value 1
// that names the state, for readers that show only keys and values.
std::string state_counter_key(Kinect2State state);

// Adds the counters kinect2_state, kinect2_state_<name>, kinect2_frames, kinect2_stalls,
// kinect2_usb_resets, kinect2_reconnects and kinect2_usb_hotplug. When the daemon is reading
// (hb->state running or idle) it also sets hb->state from the device state and, unless the device
// is connected, puts the status line ("waiting for device: no Kinect V2 on USB (...)") in
// hb->last_error. Paused, stopping, finished and error (a stuck driver) are left as they are.
void annotate_heartbeat(const Kinect2Status& status, depthfuse::heartbeat_t* hb);

}  // namespace depthfuse::capture
