#include "frame_measure.hpp"

#include <cmath>
#include <cstdio>
#include <string>

namespace depthfuse {

Result<size_t> measure_frame(const Frame& frame, const ReconstructionConfig& c, MeasurementImage* m,
                             const CameraVelocity* velocity) {
  const double readout_s = row_readout_s(frame, c.sensor);
  if (velocity && readout_s > 0.0) {
    Frame at_mid_row;
    at_mid_row.utime = frame.utime;
    at_mid_row.intrinsics = frame.intrinsics;
    if (undo_rolling_shutter(frame, *velocity, readout_s, &at_mid_row.depth)) {
      at_mid_row.color = frame.color;
      DF_RETURN_IF_ERROR(backproject(at_mid_row, c.sensor, c.fusion, m));
      return prefilter(c.prefilter, m, c.fusion.threads);
    }
  }
  DF_RETURN_IF_ERROR(backproject(frame, c.sensor, c.fusion, m));
  return prefilter(c.prefilter, m, c.fusion.threads);
}

Status no_measurement(const DepthImage& depth, const SensorModelConfig& sensor) {
  size_t zero = 0;
  for (float z : depth.depth_m) zero += !(z > 0.0f);
  const size_t n = depth.depth_m.size();
  char range[64];
  std::snprintf(range, sizeof(range), "[%g, %g] m", sensor.min_depth_m, sensor.max_depth_m);
  std::string why = std::to_string(n) + " pixels, ";
  if (zero == n)
    why += "all 0 (no measurement)";
  else
    why += std::to_string(zero) + " without a measurement and the other " + std::to_string(n - zero) +
           " outside the sensor's range " + range + " (a wrong depth scale?)";
  return invalid_argument("no valid depth measurement: " + why);
}

double rotation_between_deg(const Pose& a, const Pose& b) {
  const Eigen::AngleAxisd d(a.linear().transpose() * b.linear());
  return std::abs(d.angle()) * 180.0 / M_PI;
}

}  // namespace depthfuse
