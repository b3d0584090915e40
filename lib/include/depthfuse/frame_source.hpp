// The one interface every driver (kinect2, replay, synthetic, LCM log) implements.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse {

// What a live device says about itself beside its frames, for the heartbeat of the daemon that
// reads it: whether it is streaming, and why not.
struct DeviceStatus {
  enum class Reading {
    kStreaming,  // frames are coming
    kWaiting,    // nothing to read yet: no device attached, or it is being opened
    kFailing,    // the device stopped delivering and is being recovered
  };
  Reading reading = Reading::kWaiting;
  // One line, the state first: "waiting for device: no Kinect V2 on USB (...)".
  std::string summary;
  // The driver's figures, named after the driver ("kinect2_frames"), in a fixed order.
  std::vector<std::pair<std::string, double>> counters;
};

class FrameSource {
 public:
  virtual ~FrameSource() = default;

  // The next frame. Status kEndOfStream when a finite source is exhausted; kUnavailable when a live
  // device is (temporarily) gone; any other error names the broken input.
  virtual Result<Frame> next() = 0;

  // "tum:/data/seq (798 frames)" and the like, for logs and heartbeats.
  virtual std::string describe() const = 0;

  // Frames per second the source produces on its own (a recording's pace), if it has one.
  virtual std::optional<double> nominal_rate_hz() const { return std::nullopt; }

  // Total number of frames for finite sources.
  virtual std::optional<size_t> frame_count() const { return std::nullopt; }

  // Back to the first frame (for --loop). Live sources return kUnsupported.
  virtual Status rewind() { return unsupported("this source cannot rewind"); }

  // When the frame `last` (the one next() returned last) was recorded, in microseconds, for a
  // replay at the recorded pace: the frame's own time, unless the source keeps the recording's
  // clock apart (an LCM log: lcm-logger's receive time).
  virtual int64_t recorded_utime(const Frame& last) const { return last.utime; }

  // True when a replay should follow the recorded pace unless told otherwise (a recorded session),
  // rather than nominal_rate_hz().
  virtual bool paced_as_recorded() const { return false; }

  // The device's own state, for live device sources; nullopt for the others. Thread-safe: a
  // heartbeat thread may call it while another thread is inside next().
  virtual std::optional<DeviceStatus> device_status() const { return std::nullopt; }
};

}  // namespace depthfuse
