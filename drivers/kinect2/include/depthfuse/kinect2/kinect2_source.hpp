// The Kinect V2 frame source (libfreenect2). Depth in metres, undistorted, with the device's
// factory intrinsics (or its calibration from the config, chosen by serial) and its serial on every
// frame; colour registered to depth. It survives the real world: while no Kinect is attached next()
// returns kUnavailable after a bounded wait (sleeping on USB hotplug events, never spinning) and it
// resumes by itself when one is plugged in; a device that stops delivering frames is closed, reset
// on USB and reopened. status() says which of these is going on, for the capture daemon's heartbeat.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "depthfuse/app_config.hpp"
#include "depthfuse/frame_source.hpp"
#include "depthfuse/kinect2/device_link.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse::kinect2 {

struct Kinect2Options {
  std::string serial;                  // empty = the first Kinect V2 found
  std::string pipeline = "depthfuse";  // depthfuse | cpu | opengl | opencl | cuda (libfreenect2's)
  double min_depth_m = 0.5;            // libfreenect2 Config::MinDepth
  double max_depth_m = 4.5;            // libfreenect2 Config::MaxDepth
  bool bilateral_filter = true;        // Config::EnableBilateralFilter
  bool edge_aware_filter = true;       // Config::EnableEdgeAwareFilter
  int decoder_threads = 1;             // the depthfuse pipeline's decoder: 1 or 2
  double stall_timeout_s = 2.0;        // connected and no frame for this long: close, USB reset, reopen
  double first_frame_timeout_s = 10.0; // the same for the first frame after opening
  double open_retry_interval_s = 1.0;  // a present device that failed to open is retried this often
  double max_wait_s = 1.0;             // longest a next() call blocks before returning kUnavailable
  std::vector<DeviceCalibration> calibrations;  // per serial; overrides the factory pinhole
};

// The [capture] kinect2_* keys and [[devices]] of the config, validated: kInvalidArgument naming
// the key for a bad value, kUnsupported for a pipeline that is not compiled into libfreenect2.
Result<Kinect2Options> kinect2_options_from_config(const std::string& serial_or_empty,
                                                   const AppConfig& config);

struct Kinect2Status {
  Kinect2State state = Kinect2State::kWaitingForDevice;
  std::string detail;          // why: "no Kinect V2 on USB", "no frame for 2.3 s (limit 2.0 s)", ...
  std::string serial;          // the open device's serial, else the requested one (may be empty)
  std::string pipeline;
  bool usb_hotplug = false;    // hotplug events (true) or polling the bus (false)
  uint64_t frames = 0;         // delivered by next()
  uint32_t stalls = 0;
  uint32_t usb_resets = 0;
  uint32_t reconnects = 0;     // successful opens after the first
  uint64_t dropped_packets = 0;  // packets the depthfuse decoder refused (each with its reason)
  int64_t last_frame_utime = 0;

  // One line for logs and heartbeats:
  // "connected: streaming (serial 012345, depthfuse pipeline, 1200 frames, 0 stalls, 0 USB resets,
  // 0 reconnects)"
  std::string summary() const;
};

// The status as every device source gives it (FrameSource::device_status): streaming when
// connected, waiting while there is no device to read (none attached, opening it), failing while a
// stalled device is reset; the summary line; and the counters kinect2_state (the position of the
// state in Kinect2State), kinect2_state_<name> (1, the one key that names the state),
// kinect2_frames, kinect2_stalls, kinect2_usb_resets, kinect2_reconnects and kinect2_usb_hotplug.
DeviceStatus to_device_status(const Kinect2Status& status);

class Kinect2Source : public FrameSource {
 public:
  // Thread-safe: a heartbeat thread may call it while another thread is inside next().
  virtual Kinect2Status status() const = 0;
  // to_device_status(status()).
  std::optional<DeviceStatus> device_status() const final;
};

// kUnsupported / kInvalidArgument for a bad configuration, kUnavailable when USB cannot be
// accessed at all. No Kinect attached is not an error here: the source waits for one (see above).
Result<std::unique_ptr<Kinect2Source>> open_kinect2(const Kinect2Options& options);

// The entry point of the source factory (drivers/source_factory.cpp): "kinect2[:serial]".
Result<std::unique_ptr<FrameSource>> open_kinect2_source(const std::string& serial_or_empty,
                                                         const AppConfig& config);

// The device status of "kinect2[:serial]" before the source could be opened: waiting for the
// device, `detail` saying why ("" while it is being opened). The factory's
// device_status_before_open.
DeviceStatus kinect2_status_before_open(const std::string& serial_or_empty, const AppConfig& config,
                                        const std::string& detail);

// The status of `source` when it is a Kinect V2 source, for daemons that hold a FrameSource.
const Kinect2Source* as_kinect2_source(const FrameSource& source);

}  // namespace depthfuse::kinect2
