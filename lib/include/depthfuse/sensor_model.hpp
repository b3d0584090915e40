// The paper's per-measurement covariance, aligned with the line of sight.
#pragma once

#include <cmath>

#include <Eigen/Core>

#include "depthfuse/config.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse {

class SensorModel {
 public:
  SensorModel(const SensorModelConfig& config, const CameraIntrinsics& intrinsics);

  // Variances (m^2) along the pixel's x, y and the line of sight, at depth z.
  double lateral_variance_x_m2(double z_m) const { return kx_ * z_m * z_m; }
  double lateral_variance_y_m2(double z_m) const { return ky_ * z_m * z_m; }
  double axial_sigma_m(double z_m) const {
    return c_.alpha2_per_m * z_m * z_m + c_.alpha1 * z_m + c_.alpha0_m;
  }
  double axial_variance_m2(double z_m) const {
    const double s = axial_sigma_m(z_m);
    return c_.lambda2 * s * s;
  }

  // Information (inverse variance, 1/m^2) across the ray in x and y and along it, at depth z: the
  // same curve as the variances above, in float for the per-measurement path.
  void information_weights(float z_m, float* w_x, float* w_y, float* w_z) const {
    const float inv_z2 = 1.0f / (z_m * z_m);
    const float sigma = (a2_ * z_m + a1_) * z_m + a0_;
    *w_x = inv_kx_ * inv_z2;
    *w_y = inv_ky_ * inv_z2;
    *w_z = inv_lambda2_ / (sigma * sigma);
  }

  // How far the measurement's ellipsoid reaches along its ray at depth z (m): sqrt(lambda2)
  // sigma(z), in float for the per-pixel path.
  float axial_reach_m(float z_m) const {
    return ((a2_ * z_m + a1_) * z_m + a0_) * sqrt_lambda2_;
  }

  // Information matrix (inverse covariance) of a measurement at p_cam_m, in the camera frame: the
  // ellipsoid's third axis is the ray through the point.
  Eigen::Matrix3f information_cam(const Eigen::Vector3f& p_cam_m) const;

  const SensorModelConfig& config() const { return c_; }

 private:
  SensorModelConfig c_;
  double kx_ = 0.0, ky_ = 0.0;  // lambda1 (beta / sqrt 12)^2
  // The same constants in float for information_weights().
  float inv_kx_ = 0, inv_ky_ = 0, a0_ = 0, a1_ = 0, a2_ = 0, inv_lambda2_ = 0, sqrt_lambda2_ = 0;
};

}  // namespace depthfuse
