// Lens distortion of a recorded depth camera, undone once per frame by a nearest-pixel lookup that
// is built once per camera.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::replay {

// OpenCV's (Brown-Conrady) model, its order: a ray through normalised (x, y) lands on the image at
// x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2), and likewise for y.
struct LensDistortion {
  double k1 = 0, k2 = 0, p1 = 0, p2 = 0, k3 = 0;
  bool is_zero() const { return k1 == 0 && k2 == 0 && p1 == 0 && p2 == 0 && k3 == 0; }
};

// For every pixel of the undistorted image (the same intrinsics, so nothing downstream changes),
// the pixel of the recorded image its ray falls on, rounded to the nearest: depth is copied, never
// interpolated, since a blend across an edge is a surface that is not there.
class Undistorter {
 public:
  static constexpr int32_t kOutside = -1;

  // Refuses coefficients whose map folds over (two undistorted pixels in a row or column taking
  // their samples in the opposite order: a lens model past its valid radius) or moves a pixel by
  // more than an eighth of the image's diagonal (no depth camera's lens; most likely the wrong
  // order or units), naming which.
  static Result<Undistorter> create(const CameraIntrinsics& K, const LensDistortion& d);

  // Index into the recorded image, row-major, per undistorted pixel; kOutside if the ray falls
  // outside the recorded image.
  const std::vector<int32_t>& source() const { return source_; }
  // The largest distance from an undistorted pixel to its sample, px (for the log).
  double max_shift_px() const { return max_shift_px_; }

 private:
  std::vector<int32_t> source_;
  double max_shift_px_ = 0;
};

}  // namespace depthfuse::replay
