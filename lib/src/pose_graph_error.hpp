// Internal: the error of one pose-graph edge, templated on the scalar so that the solver can
// differentiate it automatically (T = double to evaluate, a dual number for the Jacobian). Free of
// the solver's headers: pose_graph.cpp wraps it.
#pragma once

#include <cmath>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace depthfuse::pose_graph {

template <typename T>
using Vector3 = Eigen::Matrix<T, 3, 1>;
template <typename T>
using Vector6 = Eigen::Matrix<T, 6, 1>;

// Log of SE(3) for the pose (q, t), rotation first: (w, V(w)^-1 t). q is a unit quaternion.
// Branches compare values only, so a dual number takes the same branch as its value; near zero
// angle the closed forms divide 0 by 0 and their series are used instead.
template <typename T>
Vector6<T> se3_log(Eigen::Quaternion<T> q, const Vector3<T>& t) {
  using std::atan2;
  using std::sqrt;
  // q and -q are the same rotation; w >= 0 picks the angle in [0, pi].
  if (q.w() < T(0)) q.coeffs() = -q.coeffs();
  const Vector3<T> v = q.vec();
  const T sin_half2 = v.squaredNorm();
  Vector3<T> w;
  T half_cot_half;  // (theta / 2) * cot(theta / 2), from the quaternion without more trigonometry
  if (sin_half2 > T(1e-10)) {
    const T sin_half = sqrt(sin_half2);
    const T half_angle = atan2(sin_half, q.w());
    w = v * (T(2) * half_angle / sin_half);
    half_cot_half = half_angle * q.w() / sin_half;
  } else {
    // theta / sin(theta / 2) = 2 / cos(theta / 2) to the first order.
    w = v * (T(2) / q.w());
    half_cot_half = T(1) - sin_half2 / T(3);
  }
  // V^-1 = I - [w]x / 2 + c [w]x^2, c = (1 - (theta / 2) cot(theta / 2)) / theta^2.
  const T theta2 = w.squaredNorm();
  const T c = theta2 > T(1e-4) ? (T(1) - half_cot_half) / theta2
                               : T(1.0 / 12.0) + theta2 / T(720.0);
  const Vector3<T> w_x_t = w.cross(t);
  Vector6<T> e;
  e.template head<3>() = w;
  e.template tail<3>() = t - T(0.5) * w_x_t + c * w.cross(w_x_t);
  return e;
}

// One edge's whitened error: sqrt_information * Log(T_from_to^-1 * T_world_from^-1 * T_world_to).
// Poses are a unit quaternion (x, y, z, w: Eigen's storage) and a translation.
struct EdgeError {
  Eigen::Quaterniond q_to_from_measured;  // the inverse of the measured rotation
  Eigen::Vector3d t_from_to_measured;
  Eigen::Matrix<double, 6, 6> sqrt_information;  // S with S^T S = information

  template <typename T>
  bool operator()(const T* q_world_from_p, const T* t_world_from_p, const T* q_world_to_p,
                  const T* t_world_to_p, T* residual_p) const {
    const Eigen::Map<const Eigen::Quaternion<T>> q_world_from(q_world_from_p);
    const Eigen::Map<const Vector3<T>> t_world_from(t_world_from_p);
    const Eigen::Map<const Eigen::Quaternion<T>> q_world_to(q_world_to_p);
    const Eigen::Map<const Vector3<T>> t_world_to(t_world_to_p);
    const Eigen::Quaternion<T> q_from_world = q_world_from.conjugate();
    // T_from_to as the states have it, then its difference from the measurement.
    const Eigen::Quaternion<T> q_from_to = q_from_world * q_world_to;
    const Vector3<T> t_from_to = q_from_world * (t_world_to - t_world_from);
    const Eigen::Quaternion<T> q_measured_inv = q_to_from_measured.cast<T>();
    const Eigen::Quaternion<T> q_error = q_measured_inv * q_from_to;
    const Vector3<T> t_error = q_measured_inv * (t_from_to - t_from_to_measured.cast<T>());
    Eigen::Map<Vector6<T>> residual(residual_p);
    residual = sqrt_information.cast<T>() * se3_log(q_error, t_error);
    return true;
  }
};

}  // namespace depthfuse::pose_graph
