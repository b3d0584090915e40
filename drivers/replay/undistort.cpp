#include "depthfuse/replay/undistort.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>

namespace depthfuse::replay {

Result<Undistorter> Undistorter::create(const CameraIntrinsics& K, const LensDistortion& d) {
  for (double c : {d.k1, d.k2, d.p1, d.p2, d.k3})
    if (!std::isfinite(c)) return invalid_argument("lens distortion: a coefficient is not finite");
  if (!K.valid()) return invalid_argument("lens distortion: the camera's intrinsics are invalid");
  const int w = K.width, h = K.height;
  Undistorter out;
  out.source_.assign(static_cast<size_t>(w) * h, kOutside);
  if (d.is_zero()) {
    for (size_t i = 0; i < out.source_.size(); ++i) out.source_[i] = static_cast<int32_t>(i);
    return out;
  }

  // The map cv::initUndistortRectifyMap makes with the same camera matrix out as in (so the
  // undistorted image keeps the intrinsics the rest of depthfuse is given), evaluated here: it is
  // the model's forward direction, a few lines, and calib3d is a library (with features2d and
  // flann behind it) the rig would load for nothing else. The tests compare the two.
  std::vector<float> map_xs(static_cast<size_t>(w) * h), map_ys(map_xs.size());
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const double x = (u - K.cx) / K.fx, y = (v - K.cy) / K.fy;
      const double r2 = x * x + y * y;
      const double radial = 1 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3));
      const double xd = x * radial + 2 * d.p1 * x * y + d.p2 * (r2 + 2 * x * x);
      const double yd = y * radial + d.p1 * (r2 + 2 * y * y) + 2 * d.p2 * x * y;
      map_xs[static_cast<size_t>(v) * w + u] = static_cast<float>(K.fx * xd + K.cx);
      map_ys[static_cast<size_t>(v) * w + u] = static_cast<float>(K.fy * yd + K.cy);
    }
  auto map_x = [&](int u, int v) { return map_xs[static_cast<size_t>(v) * w + u]; };
  auto map_y = [&](int u, int v) { return map_ys[static_cast<size_t>(v) * w + u]; };

  // A fold: where the model's radial polynomial turns back, neighbouring undistorted pixels take
  // their samples in reverse order, and the image would be mirrored there.
  auto where = [](int u, int v) {
    return "(" + std::to_string(u) + ", " + std::to_string(v) + ")";
  };
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const float x = map_x(u, v), y = map_y(u, v);
      if (!std::isfinite(x) || !std::isfinite(y))
        return invalid_argument("lens distortion: no sample for pixel " + where(u, v));
      if (u > 0 && !(x > map_x(u - 1, v)))
        return invalid_argument("lens distortion: the map folds over along row " +
                                std::to_string(v) + " at pixel " + where(u, v) +
                                " (the coefficients are past their valid radius)");
      if (v > 0 && !(y > map_y(u, v - 1)))
        return invalid_argument("lens distortion: the map folds over along column " +
                                std::to_string(u) + " at pixel " + where(u, v) +
                                " (the coefficients are past their valid radius)");
      out.max_shift_px_ = std::max(out.max_shift_px_, std::hypot(double{x} - u, double{y} - v));
    }
  const double limit_px = std::hypot(w, h) / 8.0;
  if (out.max_shift_px_ > limit_px) {
    std::ostringstream m;
    m << "lens distortion moves pixels by up to " << out.max_shift_px_ << " px, more than "
      << limit_px << " (an eighth of the image's diagonal): not a depth camera's lens; are the "
      << "coefficients in OpenCV's order k1 k2 p1 p2 k3?";
    return invalid_argument(m.str());
  }
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      // Nearest pixel, as cv::remap with INTER_NEAREST, but looked up once: per frame only a copy.
      const long su = std::lround(map_x(u, v)), sv = std::lround(map_y(u, v));
      if (su >= 0 && su < w && sv >= 0 && sv < h)
        out.source_[static_cast<size_t>(v) * w + u] = static_cast<int32_t>(sv * w + su);
    }
  return out;
}

}  // namespace depthfuse::replay
