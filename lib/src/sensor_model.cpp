#include "depthfuse/sensor_model.hpp"

#include <cmath>

#include "geometry.hpp"

namespace depthfuse {

SensorModel::SensorModel(const SensorModelConfig& config, const CameraIntrinsics& intrinsics)
    : c_(config) {
  const double bx = c_.beta_x_rad > 0 ? c_.beta_x_rad : 1.0 / intrinsics.fx;
  const double by = c_.beta_y_rad > 0 ? c_.beta_y_rad : 1.0 / intrinsics.fy;
  // A pixel's footprint is a uniform distribution of width beta*z: variance (beta z)^2 / 12.
  kx_ = c_.lambda1 * bx * bx / 12.0;
  ky_ = c_.lambda1 * by * by / 12.0;
  inv_kx_ = static_cast<float>(1.0 / kx_);
  inv_ky_ = static_cast<float>(1.0 / ky_);
  a0_ = static_cast<float>(c_.alpha0_m);
  a1_ = static_cast<float>(c_.alpha1);
  a2_ = static_cast<float>(c_.alpha2_per_m);
  inv_lambda2_ = static_cast<float>(1.0 / c_.lambda2);
  sqrt_lambda2_ = static_cast<float>(std::sqrt(c_.lambda2));
}

Eigen::Matrix3f SensorModel::information_cam(const Eigen::Vector3f& p_cam_m) const {
  float w_x, w_y, w_z;
  information_weights(p_cam_m.z(), &w_x, &w_y, &w_z);
  Eigen::Matrix3f L;
  ray_information(p_cam_m, Eigen::Vector3f::UnitY(), w_x, w_y, w_z, &L);
  return L;
}

}  // namespace depthfuse
