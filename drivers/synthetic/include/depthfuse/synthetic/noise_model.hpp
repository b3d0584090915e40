// The time-of-flight error model of the synthetic source: what a Kinect V2 does to a perfect depth
// map. Each effect has its own switch so that tests can look at one at a time; the defaults are all
// on and realistic.
#pragma once

#include <cmath>

#include "depthfuse/status.hpp"

namespace depthfuse::synthetic {

struct NoiseConfig {
  bool enabled = true;  // master switch; false = exact depth (range gating still applies)

  // Axial (along the optical axis) Gaussian noise, Kinect V2 model of Fankhauser et al. 2015,
  // "Kinect v2 for mobile robot navigation: evaluation and modeling", ICAR 2015:
  //   sigma_z[mm] = 1.5 - 0.5 z + 0.3 z^2 + 0.1 z^1.5 theta^2 / (pi/2 - theta)^2
  // with z the depth in metres and theta the incidence angle (between the ray and the surface
  // normal). The angle term diverges at grazing incidence; theta is clamped to
  // axial_max_incidence_deg (those pixels mostly drop out anyway, see below).
  bool axial_enabled = true;
  double axial_scale = 1.0;  // multiplies sigma_z (1 = the published model)
  double axial_max_incidence_deg = 80.0;

  // Flying pixels: a pixel whose 3x3 neighbourhood (in the exact depth map) spans a depth
  // discontinuity of more than max(flying_min_jump_m, flying_min_jump_fraction * z_near) gets, with
  // probability flying_probability, a depth drawn uniformly between the nearest and the farthest
  // depth of that neighbourhood (the pixel integrates light from foreground and background).
  bool flying_enabled = true;
  double flying_probability = 0.3;
  double flying_min_jump_m = 0.05;
  double flying_min_jump_fraction = 0.03;

  // Multipath interference (MPI): light bouncing off a second surface of a concave corner arrives
  // late, so the measured range is too long. Model: a positive range bias
  //   b(d) = mpi_max_bias_m * (1 - d / mpi_range_m)^2   for d < mpi_range_m, else 0
  // where d is the distance from the point to the nearest concave edge (Scene::concave_edge_
  // distance_m). Defaults: 10 mm at the edge, 4.4 mm at 5 cm, 1.1 mm at 10 cm, none beyond 15 cm.
  // The bias is added along the ray (range), so depth grows by b * z / range.
  bool mpi_enabled = true;
  double mpi_max_bias_m = 0.010;
  double mpi_range_m = 0.15;

  // Dropouts (no return, depth 0), more likely at grazing incidence and far away:
  //   p = dropout_probability
  //     + ((theta - dropout_grazing_start_deg) / (90 - dropout_grazing_start_deg))^2
  //                                                       (only where theta > grazing start)
  //     + dropout_far_probability * (z - dropout_far_start_m) / (max_depth - dropout_far_start_m)
  //                                                       (only where z > far start)
  bool dropout_enabled = true;
  double dropout_probability = 0.002;
  double dropout_grazing_start_deg = 65.0;
  double dropout_far_start_m = 3.5;
  double dropout_far_probability = 0.10;

  // Sparse outliers: with this probability a valid pixel reports a depth drawn uniformly from the
  // sensor's range along its ray.
  bool outlier_enabled = true;
  double outlier_probability = 0.0005;

  // Checks ranges (probabilities in [0,1], non-negative lengths); the error names the field.
  Status validate() const;

  // A configuration with every effect off except the ones a test turns on again.
  static NoiseConfig none() {
    NoiseConfig c;
    c.axial_enabled = c.flying_enabled = c.mpi_enabled = c.dropout_enabled = c.outlier_enabled =
        false;
    return c;
  }
};

// sigma_z of the Fankhauser et al. model in metres (theta in radians, clamped as configured).
inline double fankhauser_axial_sigma_m(double z_m, double theta_rad, double max_theta_rad) {
  constexpr double kHalfPi = 1.57079632679489661923;
  const double th = std::fmin(std::fabs(theta_rad), max_theta_rad);
  const double g = th / (kHalfPi - th);
  const double sigma_mm = 1.5 - 0.5 * z_m + 0.3 * z_m * z_m + 0.1 * z_m * std::sqrt(z_m) * g * g;
  return 1e-3 * sigma_mm;
}

// The MPI bias of NoiseConfig at distance d from a concave edge, in metres.
inline double mpi_bias_m(const NoiseConfig& c, double edge_distance_m) {
  if (!(edge_distance_m < c.mpi_range_m) || c.mpi_range_m <= 0.0) return 0.0;
  const double s = 1.0 - edge_distance_m / c.mpi_range_m;
  return c.mpi_max_bias_m * s * s;
}

}  // namespace depthfuse::synthetic
