// The one interface every driver (kinect2, replay, synthetic, LCM log) implements.
#pragma once

#include <memory>
#include <optional>
#include <string>

#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse {

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
};

}  // namespace depthfuse
