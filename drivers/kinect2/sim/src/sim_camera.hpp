// The simulated Kinect V2's optics: from the image of an ideal pinhole camera (what the synthetic
// renderer draws, and what the driver's undistortion gives back) to the depth and IR images the
// device's depth camera would measure, distorted and in libfreenect2's layout, ready for the
// packet encoder.
#pragma once

#include <vector>

#include "depthfuse/kinect2/depth_decoder.hpp"
#include "depthfuse/kinect2/raw_depth.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::kinect2::sim {

class SimCamera {
 public:
  // The pinhole is that of `calibration` (fx, fy, cx, cy, 512x424); its distortion decides
  // where each distorted pixel looks.
  explicit SimCamera(const IrCalibration& calibration);

  // The pinhole the renderer must draw with (the intrinsics the driver publishes).
  const CameraIntrinsics& pinhole() const { return pinhole_; }

  // Depth (metres, 0 = no return) along each distorted pixel's ray, from `pinhole_depth` drawn
  // with pinhole(): inverse depth interpolated bilinearly between four neighbours on one surface
  // (exact on planes), else the nearest one. IR: an active illuminator's return, falling with the
  // square of the depth. Both images are resized on first use, then reused.
  void measure(const DepthImage& pinhole_depth, DepthImage* depth, IrImage* ir) const;

 private:
  CameraIntrinsics pinhole_;
  // Per distorted pixel: where its ray meets the pinhole image (pixel coordinates); x < 0 when
  // outside it.
  std::vector<float> source_x_, source_y_;
};

}  // namespace depthfuse::kinect2::sim
