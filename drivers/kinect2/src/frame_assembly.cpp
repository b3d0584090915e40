#include "depthfuse/kinect2/frame_assembly.hpp"

#include "depthfuse/base/clock.hpp"
#include "depthfuse/kinect2/conversion.hpp"

namespace depthfuse::kinect2 {

Result<std::unique_ptr<FrameAssembly>> FrameAssembly::create(
    const libfreenect2::Freenect2Device::IrCameraParams& ir,
    const libfreenect2::Freenect2Device::ColorCameraParams& color, std::string serial,
    std::unique_ptr<PacketDecoding> decoding) {
  Result<CameraIntrinsics> intrinsics = intrinsics_from_ir_params(ir);
  if (!intrinsics.is_ok()) return intrinsics.status();
  return std::unique_ptr<FrameAssembly>(
      new FrameAssembly(ir, color, intrinsics.value(), std::move(serial), std::move(decoding)));
}

FrameAssembly::FrameAssembly(const libfreenect2::Freenect2Device::IrCameraParams& ir,
                             const libfreenect2::Freenect2Device::ColorCameraParams& color,
                             CameraIntrinsics intrinsics, std::string serial,
                             std::unique_ptr<PacketDecoding> decoding)
    : registration_(ir, color),
      intrinsics_(intrinsics),
      serial_(std::move(serial)),
      decoding_(std::move(decoding)),
      decoded_(kDepthWidth, kDepthHeight, 4),
      undistorted_(kDepthWidth, kDepthHeight, 4),
      registered_(kDepthWidth, kDepthHeight, 4) {}

Result<Frame> FrameAssembly::assemble(const libfreenect2::Frame& depth,
                                      const libfreenect2::Frame* color) {
  Result<Frame> frame = assemble_counted(depth, color);
  if (!frame.is_ok()) ++stats_.dropped;
  return frame;
}

Result<Frame> FrameAssembly::assemble_counted(const libfreenect2::Frame& depth_in,
                                              const libfreenect2::Frame* color) {
  const int64_t start_ns = thread_cpu_ns();
  const libfreenect2::Frame* depth = &depth_in;
  double decode_ms = 0;
  if (decoding_) {
    DF_RETURN_IF_ERROR(decoding_->decode(*depth, &decoded_));
    depth = &decoded_;
    decode_ms = (thread_cpu_ns() - start_ns) * 1e-6;
  }
  if (depth->width != static_cast<size_t>(kDepthWidth) ||
      depth->height != static_cast<size_t>(kDepthHeight) || depth->bytes_per_pixel != 4)
    return corrupt("libfreenect2 delivered a depth frame of " + std::to_string(depth->width) +
                   "x" + std::to_string(depth->height) + "x" +
                   std::to_string(depth->bytes_per_pixel) + " bytes, expected 512x424x4");
  const bool have_color =
      color != nullptr && color->width == static_cast<size_t>(kColorWidth) &&
      color->height == static_cast<size_t>(kColorHeight) && color->bytes_per_pixel == 4 &&
      (color->format == libfreenect2::Frame::BGRX || color->format == libfreenect2::Frame::RGBX);

  Frame frame;
  frame.utime = now_utime();
  frame.sequence = depth->sequence;
  frame.sensor_serial = serial_;
  frame.intrinsics = intrinsics_;
  if (have_color)
    registration_.apply(color, depth, &undistorted_, &registered_, /*enable_filter=*/true);
  else
    registration_.undistortDepth(depth, &undistorted_);
  DF_RETURN_IF_ERROR(convert_depth_frame(undistorted_, &frame.depth));
  if (have_color)
    DF_RETURN_IF_ERROR(convert_registered_color(registered_, color->format, &frame.color));
  ++stats_.frames;
  stats_.decode_ms += decode_ms;
  stats_.assemble_ms += (thread_cpu_ns() - start_ns) * 1e-6;
  return frame;
}

}  // namespace depthfuse::kinect2
