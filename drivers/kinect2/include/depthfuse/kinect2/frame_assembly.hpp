// What the driver does with a frame set once libfreenect2 has handed it over: a raw depth packet
// through depthfuse's decoder (the depthfuse pipeline), undistortion and colour registration
// (libfreenect2's Registration), metres, and the Frame the capture daemon publishes. The Kinect V2
// source and the simulated sensor (kinect2sim) both run their frames through it, so the simulator
// exercises the real path.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include <libfreenect2/frame_listener.hpp>
#include <libfreenect2/libfreenect2.hpp>
#include <libfreenect2/registration.h>

#include "depthfuse/kinect2/packet_decoding.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::kinect2 {

// What assemble() did, for the status: frames made and refused, and the CPU time of the calling
// thread it spent on the frames it made (milliseconds, totals since the assembly was made).
struct AssemblyStats {
  uint64_t frames = 0;
  uint64_t dropped = 0;    // refused (a bad packet, a malformed frame): each returned its error
  double decode_ms = 0;    // the depthfuse decoder (0 for libfreenect2's pipelines)
  double assemble_ms = 0;  // everything in assemble(), the decoder included
};

class FrameAssembly {
 public:
  // `ir` is the pinhole (and the factory distortion) the undistorted image follows and the frames
  // carry as intrinsics; `decoding` is null unless frames are raw packets (the depthfuse pipeline).
  static Result<std::unique_ptr<FrameAssembly>> create(
      const libfreenect2::Freenect2Device::IrCameraParams& ir,
      const libfreenect2::Freenect2Device::ColorCameraParams& color, std::string serial,
      std::unique_ptr<PacketDecoding> decoding);

  // The frame of a depth frame (float mm, or a raw packet for the depthfuse pipeline) and, when
  // it is not null and a 1920x1080 BGRX/RGBX image, the colour registered to it. The frame's
  // sequence is the device's (depth->sequence); utime is the host clock now. kCorrupt for a depth
  // frame of the wrong shape, kInvalidArgument for a packet the decoder refuses; either is counted
  // as dropped and the next frame is assembled as if it had not come.
  Result<Frame> assemble(const libfreenect2::Frame& depth, const libfreenect2::Frame* color);

  const AssemblyStats& stats() const { return stats_; }

 private:
  Result<Frame> assemble_counted(const libfreenect2::Frame& depth, const libfreenect2::Frame* color);

  FrameAssembly(const libfreenect2::Freenect2Device::IrCameraParams& ir,
                const libfreenect2::Freenect2Device::ColorCameraParams& color,
                CameraIntrinsics intrinsics, std::string serial,
                std::unique_ptr<PacketDecoding> decoding);

  libfreenect2::Registration registration_;
  CameraIntrinsics intrinsics_;
  std::string serial_;
  std::unique_ptr<PacketDecoding> decoding_;
  libfreenect2::Frame decoded_;      // float mm from the depthfuse decoder, reused every frame
  libfreenect2::Frame undistorted_;  // float mm, reused every frame
  libfreenect2::Frame registered_;   // 4-byte colour, reused every frame
  AssemblyStats stats_;
};

}  // namespace depthfuse::kinect2
