// Internal: small inline per-point math shared by fusion and registration.
#pragma once

#include <cmath>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace depthfuse {

// A symmetric 3x3 matrix as its six distinct entries (information matrices, in 1/m^2): the
// per-point math of fusion works on these instead of full 3x3 matrices.
struct Sym3f {
  float xx, xy, xz, yy, yz, zz;

  Eigen::Matrix3f matrix() const {
    Eigen::Matrix3f m;
    m << xx, xy, xz, xy, yy, yz, xz, yz, zz;
    return m;
  }
  static Sym3f from(const Eigen::Matrix3f& m) {
    return {m(0, 0), m(0, 1), m(0, 2), m(1, 1), m(1, 2), m(2, 2)};
  }
};

inline Sym3f operator+(const Sym3f& a, const Sym3f& b) {
  return {a.xx + b.xx, a.xy + b.xy, a.xz + b.xz, a.yy + b.yy, a.yz + b.yz, a.zz + b.zz};
}

inline Eigen::Vector3f operator*(const Sym3f& a, const Eigen::Vector3f& v) {
  return {a.xx * v.x() + a.xy * v.y() + a.xz * v.z(), a.xy * v.x() + a.yy * v.y() + a.yz * v.z(),
          a.xz * v.x() + a.yz * v.y() + a.zz * v.z()};
}

// v^T A v: the squared Mahalanobis length of v under information A.
inline float mahalanobis2(const Eigen::Vector3f& v, const Sym3f& a) {
  const float x = v.x(), y = v.y(), z = v.z();
  return a.xx * x * x + a.yy * y * y + a.zz * z * z + 2.0f * (a.xy * x * y + a.xz * x * z + a.yz * y * z);
}

// Inverse by cofactors. Returns false if singular.
inline bool invert(const Sym3f& a, Sym3f* inv) {
  const float c00 = a.yy * a.zz - a.yz * a.yz, c01 = a.xz * a.yz - a.xy * a.zz,
              c02 = a.xy * a.yz - a.xz * a.yy;
  const float det = a.xx * c00 + a.xy * c01 + a.xz * c02;
  if (!(std::abs(det) > 0.0f) || !std::isfinite(det)) return false;
  const float s = 1.0f / det;
  *inv = {c00 * s, c01 * s, c02 * s, (a.xx * a.zz - a.xz * a.xz) * s,
          (a.xy * a.xz - a.xx * a.yz) * s, (a.xx * a.yy - a.xy * a.xy) * s};
  return true;
}

// Information matrix of an ellipsoid whose third axis is the unit ray direction d, with
// information w_x, w_y across and w_z along the ray. `up` (unit) is the camera's y axis in the same
// frame and fixes the lateral axes: e2 is up made orthogonal to d, e1 = e2 x d. Since e1, e2 and d
// are orthonormal, L = w_x I + (w_y - w_x) e2 e2^T + (w_z - w_x) d d^T.
inline Sym3f ray_information(const Eigen::Vector3f& d, const Eigen::Vector3f& up, float w_x,
                             float w_y, float w_z) {
  const float du = d.dot(up);
  const float s2 = 1.0f - du * du;
  Eigen::Vector3f e2 = s2 > 1e-12f ? Eigen::Vector3f((up - du * d) * (1.0f / std::sqrt(s2)))
                                   : Eigen::Vector3f(d.unitOrthogonal());
  const float a = w_y - w_x, b = w_z - w_x;
  return {w_x + a * e2.x() * e2.x() + b * d.x() * d.x(), a * e2.x() * e2.y() + b * d.x() * d.y(),
          a * e2.x() * e2.z() + b * d.x() * d.z(),       w_x + a * e2.y() * e2.y() + b * d.y() * d.y(),
          a * e2.y() * e2.z() + b * d.y() * d.z(),       w_x + a * e2.z() * e2.z() + b * d.z() * d.z()};
}

// The same for a ray that need not be unit, as a full matrix (tests, the sensor model).
inline void ray_information(const Eigen::Vector3f& ray, const Eigen::Vector3f& up, float w_x,
                            float w_y, float w_z, Eigen::Matrix3f* L) {
  *L = ray_information(Eigen::Vector3f(ray.normalized()), Eigen::Vector3f(up.normalized()), w_x, w_y,
                       w_z)
           .matrix();
}

// The paper's merge rule on the six-entry form: the product of the two Gaussians (p_e, L_e) and
// (p_n, L_n), accepted when the fused point lies inside both unit ellipsoids. merge_measurement()
// is its public face; fusion calls this inline.
inline bool merge_rule(const Eigen::Vector3f& p_e, const Sym3f& L_e, const Eigen::Vector3f& p_n,
                       const Sym3f& L_n, Eigen::Vector3f* p_fused, Sym3f* L_fused) {
  const Sym3f L = L_e + L_n;
  Sym3f C;
  if (!invert(L, &C)) return false;
  const Eigen::Vector3f delta = p_n - p_e;
  const Eigen::Vector3f from_e = C * (L_n * delta);  // p' - p_e
  if (mahalanobis2(from_e, L_e) > 1.0f) return false;
  if (mahalanobis2(Eigen::Vector3f(from_e - delta), L_n) > 1.0f) return false;  // p' - p_n
  *p_fused = p_e + from_e;
  *L_fused = L;
  return true;
}

}  // namespace depthfuse
