// Internal: small inline per-point math shared by fusion and registration.
#pragma once

#include <cmath>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace depthfuse {

// Information matrix of an ellipsoid whose third axis is the ray from the camera centre to the
// point (`ray` need not be unit), with information w_x, w_y across and w_z along the ray.
// `up` is the camera's y axis in the same frame, used to fix the lateral axes.
inline void ray_information(const Eigen::Vector3f& ray, const Eigen::Vector3f& up, float w_x,
                            float w_y, float w_z, Eigen::Matrix3f* L) {
  const Eigen::Vector3f d = ray.normalized();
  Eigen::Vector3f e1 = up.cross(d);
  const float n1 = e1.norm();
  e1 = n1 > 1e-6f ? Eigen::Vector3f(e1 / n1) : Eigen::Vector3f(d.unitOrthogonal());
  const Eigen::Vector3f e2 = d.cross(e1);
  *L = w_x * e1 * e1.transpose() + w_y * e2 * e2.transpose() + w_z * d * d.transpose();
}

// Inverse of a symmetric positive-definite 3x3 matrix by cofactors. Returns false if singular.
inline bool invert_symmetric3(const Eigen::Matrix3f& A, Eigen::Matrix3f* inv) {
  const float a = A(0, 0), b = A(0, 1), c = A(0, 2), d = A(1, 1), e = A(1, 2), f = A(2, 2);
  const float c00 = d * f - e * e, c01 = c * e - b * f, c02 = b * e - c * d;
  const float det = a * c00 + b * c01 + c * c02;
  if (!(std::abs(det) > 0.0f) || !std::isfinite(det)) return false;
  const float s = 1.0f / det;
  const float c11 = a * f - c * c, c12 = b * c - a * e, c22 = a * d - b * b;
  *inv << c00 * s, c01 * s, c02 * s, c01 * s, c11 * s, c12 * s, c02 * s, c12 * s, c22 * s;
  return true;
}

inline float mahalanobis2(const Eigen::Vector3f& r, const Eigen::Matrix3f& L) {
  return r.dot(L * r);
}

}  // namespace depthfuse
