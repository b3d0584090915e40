#include "depthfuse/types.hpp"

namespace depthfuse {

std::optional<std::string> CameraIntrinsics::physical_problem() const {
  const double min_f = 0.1 * width, max_f = 100.0 * width;
  if (!(fx >= min_f && fx <= max_f) || !(fy >= min_f && fy <= max_f))
    return "fx, fy (" + std::to_string(fx) + ", " + std::to_string(fy) +
           ") are not the focal lengths of a camera " + std::to_string(width) + " px wide (" +
           std::to_string(min_f) + " to " + std::to_string(max_f) + ")";
  if (!(cx >= 0 && cx <= width && cy >= 0 && cy <= height))
    return "cx, cy (" + std::to_string(cx) + ", " + std::to_string(cy) +
           "): the principal point lies outside the image";
  return std::nullopt;
}

}  // namespace depthfuse
