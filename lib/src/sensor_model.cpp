#include "depthfuse/sensor_model.hpp"

#include "geometry.hpp"

namespace depthfuse {

SensorModel::SensorModel(const SensorModelConfig& config, const CameraIntrinsics& intrinsics)
    : c_(config) {
  const double bx = c_.beta_x_rad > 0 ? c_.beta_x_rad : 1.0 / intrinsics.fx;
  const double by = c_.beta_y_rad > 0 ? c_.beta_y_rad : 1.0 / intrinsics.fy;
  // A pixel's footprint is a uniform distribution of width beta*z: variance (beta z)^2 / 12.
  kx_ = c_.lambda1 * bx * bx / 12.0;
  ky_ = c_.lambda1 * by * by / 12.0;
}

Eigen::Matrix3f SensorModel::information_cam(const Eigen::Vector3f& p_cam_m) const {
  const double z = p_cam_m.z();
  Eigen::Matrix3f L;
  ray_information(p_cam_m, Eigen::Vector3f::UnitY(),
                  static_cast<float>(1.0 / lateral_variance_x_m2(z)),
                  static_cast<float>(1.0 / lateral_variance_y_m2(z)),
                  static_cast<float>(1.0 / axial_variance_m2(z)), &L);
  return L;
}

}  // namespace depthfuse
