// From libfreenect2's frames and calibration to depthfuse's types. Pure functions: they touch no
// device, so they are tested on frames built in memory.
//
// Which libfreenect2 image is which: the depth frame of the pipeline is distorted (raw IR optics);
// Registration::apply (or undistortDepth) resamples it into an undistorted 512x424 image in which
// pixel (u, v) sees the ray ((u - cx) / fx, (v - cy) / fy) of the IrCameraParams pinhole, and
// writes the colour registered to that image. The driver converts those two, so the intrinsics it
// publishes are exactly the IrCameraParams pinhole (see intrinsics_from_ir_params).
#pragma once

#include <cmath>

#include <libfreenect2/frame_listener.hpp>
#include <libfreenect2/libfreenect2.hpp>

#include "depthfuse/app_config.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::kinect2 {

constexpr int kDepthWidth = 512;
constexpr int kDepthHeight = 424;
constexpr int kColorWidth = 1920;
constexpr int kColorHeight = 1080;

// libfreenect2 depth: float millimetres; non-positive, NaN and infinity mean "no measurement".
inline float depth_mm_to_m(float depth_mm) {
  return (std::isfinite(depth_mm) && depth_mm > 0.0f) ? depth_mm * 0.001f : 0.0f;
}

// A float-millimetre frame (libfreenect2::Frame::Depth, or the undistorted output of
// Registration::apply) to a DepthImage in metres, 0 where there is no measurement. `depth` is
// resized to the frame and reuses its storage. kInvalidArgument for a frame that is not 4 bytes of
// float per pixel (format Float, or Invalid as frames allocated by the caller are), has no data or
// an absurd size.
Status convert_depth_frame(const libfreenect2::Frame& depth_mm, DepthImage* depth);
Result<DepthImage> convert_depth_frame(const libfreenect2::Frame& depth_mm);

// The registered colour of Registration::apply (4 bytes per pixel, same size as the depth image;
// 0 where no colour pixel maps) to RGB8. Its byte order is that of the colour frame it was
// registered from, so the caller passes the colour frame's format: BGRX or RGBX.
Status convert_registered_color(const libfreenect2::Frame& registered,
                                libfreenect2::Frame::Format byte_order, ColorImage* color);
Result<ColorImage> convert_registered_color(const libfreenect2::Frame& registered,
                                            libfreenect2::Frame::Format byte_order);

// The pinhole of the depth camera (of the undistorted depth image). kInvalidArgument when the
// device reported nonsense (non-finite or non-positive focal length, non-finite centre).
Result<CameraIntrinsics> intrinsics_from_ir_params(
    const libfreenect2::Freenect2Device::IrCameraParams& ir, int width = kDepthWidth,
    int height = kDepthHeight);

// The factory parameters with a calibrated pinhole (fx, fy, cx, cy) in place of the factory one;
// the factory distortion coefficients (k1, k2, k3, p1, p2) are kept.
libfreenect2::Freenect2Device::IrCameraParams with_calibrated_pinhole(
    libfreenect2::Freenect2Device::IrCameraParams factory, const CameraIntrinsics& calibrated);

// A per-device calibration must describe the 512x424 depth image with a valid pinhole.
Status check_device_calibration(const DeviceCalibration& calibration);

}  // namespace depthfuse::kinect2
