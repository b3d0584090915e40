// The "depthfuse" depth pipeline: libfreenect2 delivers each raw depth packet untouched (its
// DumpPacketPipeline, which also keeps the P0 tables it read from the device) and depthfuse's own
// decoder (depth_decoder.hpp) turns it into the depth frame libfreenect2's CPU pipeline would
// have delivered, about ten times faster.
#pragma once

#include <cstdint>
#include <memory>

#include <libfreenect2/frame_listener.hpp>
#include <libfreenect2/libfreenect2.hpp>

#include "depthfuse/kinect2/depth_decoder.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse::kinect2 {

// libfreenect2's IR camera parameters as the decoder's calibration, and back.
IrCalibration ir_calibration(const libfreenect2::Freenect2Device::IrCameraParams& ir);
libfreenect2::Freenect2Device::IrCameraParams ir_camera_params(const IrCalibration& calibration);

class PacketDecoding {
 public:
  // From the P0 tables as the device sent them (DumpPacketPipeline::getDepthP0Tables: the
  // ReadP0Tables response) and the device's factory IR parameters (those libfreenect2 builds its
  // own tables from). kInvalidArgument when either is missing or malformed.
  static Result<std::unique_ptr<PacketDecoding>> create(
      const uint8_t* p0_response, size_t p0_size,
      const libfreenect2::Freenect2Device::IrCameraParams& ir, const DepthDecoderOptions& options);

  // One Frame::Raw depth frame of the DumpPacketPipeline (the packet) to `depth_mm`: 512x424
  // floats in millimetres, 0 where there is no measurement, as libfreenect2's depth frames.
  // kInvalidArgument for a frame that is not a whole packet or that repeats a sequence number;
  // `depth_mm` is then left as it was.
  Status decode(const libfreenect2::Frame& raw, libfreenect2::Frame* depth_mm);

 private:
  explicit PacketDecoding(std::unique_ptr<DepthDecoder> decoder) : decoder_(std::move(decoder)) {}
  std::unique_ptr<DepthDecoder> decoder_;
};

}  // namespace depthfuse::kinect2
