#include "depthfuse/kinect2/conversion.hpp"

#include <cstdint>
#include <cstring>
#include <string>

namespace depthfuse::kinect2 {

namespace {

// Larger than any Kinect image by far; guards the size arithmetic against garbage frames.
constexpr size_t kMaxPixels = size_t{1} << 26;

std::string frame_shape(const libfreenect2::Frame& frame) {
  return std::to_string(frame.width) + "x" + std::to_string(frame.height) + "x" +
         std::to_string(frame.bytes_per_pixel) + " bytes";
}

Status check_4_byte_frame(const libfreenect2::Frame& frame, const char* what) {
  if (frame.data == nullptr) return invalid_argument(std::string(what) + " frame has no data");
  if (frame.width == 0 || frame.height == 0 || frame.width > kMaxPixels ||
      frame.height > kMaxPixels || frame.width * frame.height > kMaxPixels)
    return invalid_argument(std::string(what) + " frame has an impossible size " +
                            frame_shape(frame));
  if (frame.bytes_per_pixel != 4)
    return invalid_argument(std::string(what) + " frame must have 4 bytes per pixel, got " +
                            frame_shape(frame));
  return Status::ok();
}

inline void bgrx_to_rgb(const uint8_t* bgrx, uint8_t* rgb) {
  rgb[0] = bgrx[2];
  rgb[1] = bgrx[1];
  rgb[2] = bgrx[0];
}

inline void rgbx_to_rgb(const uint8_t* rgbx, uint8_t* rgb) {
  rgb[0] = rgbx[0];
  rgb[1] = rgbx[1];
  rgb[2] = rgbx[2];
}

}  // namespace

Status convert_depth_frame(const libfreenect2::Frame& depth_mm, DepthImage* depth) {
  DF_RETURN_IF_ERROR(check_4_byte_frame(depth_mm, "depth"));
  if (depth_mm.format != libfreenect2::Frame::Float &&
      depth_mm.format != libfreenect2::Frame::Invalid)
    return invalid_argument("depth frame must hold floats (millimetres), got format " +
                            std::to_string(static_cast<int>(depth_mm.format)));
  const size_t n = depth_mm.width * depth_mm.height;
  depth->width = static_cast<int>(depth_mm.width);
  depth->height = static_cast<int>(depth_mm.height);
  depth->depth_m.resize(n);
  const unsigned char* in = depth_mm.data;
  float* out = depth->depth_m.data();
  for (size_t i = 0; i < n; ++i) {
    float mm;
    std::memcpy(&mm, in + i * sizeof(float), sizeof(float));  // no aliasing or alignment games
    out[i] = depth_mm_to_m(mm);
  }
  return Status::ok();
}

Result<DepthImage> convert_depth_frame(const libfreenect2::Frame& depth_mm) {
  DepthImage depth;
  DF_RETURN_IF_ERROR(convert_depth_frame(depth_mm, &depth));
  return depth;
}

Status convert_registered_color(const libfreenect2::Frame& registered,
                                libfreenect2::Frame::Format byte_order, ColorImage* color) {
  DF_RETURN_IF_ERROR(check_4_byte_frame(registered, "registered colour"));
  if (byte_order != libfreenect2::Frame::BGRX && byte_order != libfreenect2::Frame::RGBX)
    return invalid_argument("registered colour: the colour frame must be BGRX or RGBX, got format " +
                            std::to_string(static_cast<int>(byte_order)));
  const size_t n = registered.width * registered.height;
  color->width = static_cast<int>(registered.width);
  color->height = static_cast<int>(registered.height);
  color->rgb.resize(n * 3);
  const uint8_t* in = registered.data;
  uint8_t* out = color->rgb.data();
  if (byte_order == libfreenect2::Frame::BGRX) {
    for (size_t i = 0; i < n; ++i) bgrx_to_rgb(in + 4 * i, out + 3 * i);
  } else {
    for (size_t i = 0; i < n; ++i) rgbx_to_rgb(in + 4 * i, out + 3 * i);
  }
  return Status::ok();
}

Result<ColorImage> convert_registered_color(const libfreenect2::Frame& registered,
                                            libfreenect2::Frame::Format byte_order) {
  ColorImage color;
  DF_RETURN_IF_ERROR(convert_registered_color(registered, byte_order, &color));
  return color;
}

Result<CameraIntrinsics> intrinsics_from_ir_params(
    const libfreenect2::Freenect2Device::IrCameraParams& ir, int width, int height) {
  if (!(std::isfinite(ir.fx) && std::isfinite(ir.fy) && ir.fx > 0.0f && ir.fy > 0.0f))
    return invalid_argument("IR camera parameters: focal length must be finite and > 0, got fx=" +
                            std::to_string(ir.fx) + " fy=" + std::to_string(ir.fy));
  if (!(std::isfinite(ir.cx) && std::isfinite(ir.cy)))
    return invalid_argument("IR camera parameters: principal point must be finite, got cx=" +
                            std::to_string(ir.cx) + " cy=" + std::to_string(ir.cy));
  if (width <= 0 || height <= 0)
    return invalid_argument("IR camera parameters: image size must be positive, got " +
                            std::to_string(width) + "x" + std::to_string(height));
  CameraIntrinsics intrinsics;
  intrinsics.width = width;
  intrinsics.height = height;
  intrinsics.fx = ir.fx;
  intrinsics.fy = ir.fy;
  intrinsics.cx = ir.cx;
  intrinsics.cy = ir.cy;
  return intrinsics;
}

libfreenect2::Freenect2Device::IrCameraParams with_calibrated_pinhole(
    libfreenect2::Freenect2Device::IrCameraParams factory, const CameraIntrinsics& calibrated) {
  factory.fx = static_cast<float>(calibrated.fx);
  factory.fy = static_cast<float>(calibrated.fy);
  factory.cx = static_cast<float>(calibrated.cx);
  factory.cy = static_cast<float>(calibrated.cy);
  return factory;
}

Status check_device_calibration(const DeviceCalibration& calibration) {
  const CameraIntrinsics& k = calibration.intrinsics;
  const std::string who = "calibration of Kinect V2 '" + calibration.serial + "'";
  if (k.width != kDepthWidth || k.height != kDepthHeight)
    return invalid_argument(who + ": intrinsics must describe the 512x424 depth image, got " +
                            std::to_string(k.width) + "x" + std::to_string(k.height));
  if (!(k.valid() && std::isfinite(k.fx) && std::isfinite(k.fy) && std::isfinite(k.cx) &&
        std::isfinite(k.cy)))
    return invalid_argument(who + ": fx and fy must be > 0 and all intrinsics finite");
  return Status::ok();
}

}  // namespace depthfuse::kinect2
