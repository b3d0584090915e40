#include "sim_camera.hpp"

#include <algorithm>
#include <cmath>

namespace depthfuse::kinect2::sim {

namespace {

// Four neighbours are one surface when their depths are within this fraction of each other
// (a plane seen at a grazing angle still changes far less than this from pixel to pixel).
constexpr float kSameSurface = 0.03f;
// IR at 1 m and the most it gets (65535 would be saturated).
constexpr float kIrAtOneMetre = 36000.0f;
constexpr float kIrMax = 60000.0f;

}  // namespace

SimCamera::SimCamera(const IrCalibration& calibration) {
  pinhole_.width = kRawWidth;
  pinhole_.height = kRawHeight;
  pinhole_.fx = calibration.fx;
  pinhole_.fy = calibration.fy;
  pinhole_.cx = calibration.cx;
  pinhole_.cy = calibration.cy;
  source_x_.resize(kRawPixels);
  source_y_.resize(kRawPixels);
  // libfreenect2's Registration: the distorted pixel (x, y) (integer coordinates, no half-pixel
  // offset) sees the ray whose normalised coordinates distort to ((x - cx) / fx, (y - cy) / fy).
  for (int y = 0; y < kRawHeight; ++y)
    for (int x = 0; x < kRawWidth; ++x) {
      double xu, yu;
      undistort_normalised(calibration, (x - calibration.cx) / double{calibration.fx},
                           (y - calibration.cy) / double{calibration.fy}, &xu, &yu);
      const double u = calibration.fx * xu + calibration.cx;
      const double v = calibration.fy * yu + calibration.cy;
      const bool inside = u >= 0.0 && v >= 0.0 && u <= kRawWidth - 1 && v <= kRawHeight - 1;
      const size_t i = static_cast<size_t>(y) * kRawWidth + x;
      source_x_[i] = inside ? static_cast<float>(u) : -1.0f;
      source_y_[i] = inside ? static_cast<float>(v) : -1.0f;
    }
}

void SimCamera::measure(const DepthImage& pinhole_depth, DepthImage* depth, IrImage* ir) const {
  depth->width = ir->width = kRawWidth;
  depth->height = ir->height = kRawHeight;
  depth->depth_m.resize(kRawPixels);
  ir->amplitude.resize(kRawPixels);
  const float* in = pinhole_depth.depth_m.data();
  for (size_t i = 0; i < kRawPixels; ++i) {
    float d = 0.0f;
    const float u = source_x_[i], v = source_y_[i];
    if (u >= 0.0f) {
      const int u0 = std::min(static_cast<int>(u), kRawWidth - 2);
      const int v0 = std::min(static_cast<int>(v), kRawHeight - 2);
      const float fu = u - u0, fv = v - v0;
      const float* row0 = in + static_cast<size_t>(v0) * kRawWidth + u0;
      const float* row1 = row0 + kRawWidth;
      const float q[4] = {row0[0], row0[1], row1[0], row1[1]};
      const float nearest = q[(fv >= 0.5f ? 2 : 0) + (fu >= 0.5f ? 1 : 0)];
      const float lo = std::min({q[0], q[1], q[2], q[3]});
      const float hi = std::max({q[0], q[1], q[2], q[3]});
      if (lo > 0.0f && hi - lo <= kSameSurface * lo) {
        // 1/z is affine in the image on a plane: its bilinear interpolation is exact there.
        const float top = (1.0f - fu) / q[0] + fu / q[1];
        const float bottom = (1.0f - fu) / q[2] + fu / q[3];
        d = 1.0f / ((1.0f - fv) * top + fv * bottom);
      } else {
        d = nearest;
      }
    }
    depth->depth_m[i] = d;
    ir->amplitude[i] = d > 0.0f ? std::min(kIrAtOneMetre / (d * d), kIrMax) : 0.0f;
  }
}

}  // namespace depthfuse::kinect2::sim
