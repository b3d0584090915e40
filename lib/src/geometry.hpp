// Internal: small inline per-point math shared by fusion and registration.
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Core>
#include <Eigen/Geometry>

// Per-point math that a vectorised loop calls must be inlined into it, whatever the compiler's
// size heuristics say.
#if defined(__GNUC__)
#define DF_INLINE inline __attribute__((always_inline))
#else
#define DF_INLINE inline
#endif

// Before a loop whose iterations are independent but which the compiler cannot prove so (GCC
// ignores restrict on locals): lets it vectorise without run-time alias checks.
// DF_UNROLL(n): unroll the next loop n times (a short fixed-count loop whose body is branch-free).
#if defined(__GNUC__) && !defined(__clang__)
#define DF_IVDEP _Pragma("GCC ivdep")
#define DF_PRAGMA(x) _Pragma(#x)
#define DF_UNROLL(n) DF_PRAGMA(GCC unroll n)
#else
#define DF_IVDEP
#define DF_UNROLL(n)
#endif

// Before a function whose loops vectorise: on x86-64 it is compiled twice, for the baseline and
// for AVX2 (8 floats a vector instead of 4), and the loader picks the one the CPU runs. AVX2
// without FMA: the same operations, rounded the same, so results do not depend on the CPU
// (tests/pipeline/vector_clones_same_results.sh; DF_NO_VECTOR_CLONES builds the baseline only).
#if !defined(DF_NO_VECTOR_CLONES) && defined(__GNUC__) && !defined(__clang__) && \
    defined(__x86_64__) && defined(__ELF__)
#define DF_VECTOR_CLONES __attribute__((target_clones("default", "avx2")))
#else
#define DF_VECTOR_CLONES
#endif

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

DF_INLINE Sym3f operator+(const Sym3f& a, const Sym3f& b) {
  return {a.xx + b.xx, a.xy + b.xy, a.xz + b.xz, a.yy + b.yy, a.yz + b.yz, a.zz + b.zz};
}

DF_INLINE Eigen::Vector3f operator*(const Sym3f& a, const Eigen::Vector3f& v) {
  return {a.xx * v.x() + a.xy * v.y() + a.xz * v.z(), a.xy * v.x() + a.yy * v.y() + a.yz * v.z(),
          a.xz * v.x() + a.yz * v.y() + a.zz * v.z()};
}

// R v written out: Eigen's own product is a call the compiler may leave out of line, and a loop
// with a call in it is not vectorised.
DF_INLINE Eigen::Vector3f rotate(const Eigen::Matrix3f& R, const Eigen::Vector3f& v) {
  return {R(0, 0) * v.x() + R(0, 1) * v.y() + R(0, 2) * v.z(),
          R(1, 0) * v.x() + R(1, 1) * v.y() + R(1, 2) * v.z(),
          R(2, 0) * v.x() + R(2, 1) * v.y() + R(2, 2) * v.z()};
}

// v^T A v: the squared Mahalanobis length of v under information A.
DF_INLINE float mahalanobis2(const Eigen::Vector3f& v, const Sym3f& a) {
  const float x = v.x(), y = v.y(), z = v.z();
  return a.xx * x * x + a.yy * y * y + a.zz * z * z + 2.0f * (a.xy * x * y + a.xz * x * z + a.yz * y * z);
}

// Inverse by cofactors. Returns false if singular (then *inv holds non-finite values).
// Branch-free, like everything fusion's per-row loop calls.
DF_INLINE bool invert(const Sym3f& a, Sym3f* inv) {
  const float c00 = a.yy * a.zz - a.yz * a.yz, c01 = a.xz * a.yz - a.xy * a.zz,
              c02 = a.xy * a.yz - a.xz * a.yy;
  const float det = a.xx * c00 + a.xy * c01 + a.xz * c02;
  const float s = 1.0f / det;
  *inv = {c00 * s, c01 * s, c02 * s, (a.xx * a.zz - a.xz * a.xz) * s,
          (a.xy * a.xz - a.xx * a.yz) * s, (a.xx * a.yy - a.xy * a.xy) * s};
  // |det| in (0, inf): not zero, not infinite, not NaN.
  return (std::abs(det) > 0.0f) & (std::abs(det) < std::numeric_limits<float>::infinity());
}

// Information matrix of an ellipsoid whose third axis is the unit ray direction d, with
// information w_x, w_y across and w_z along the ray. `up` (unit) is the camera's y axis in the same
// frame and fixes the lateral axes: e2 is up made orthogonal to d, e1 = e2 x d. Since e1, e2 and d
// are orthonormal, L = w_x I + (w_y - w_x) e2 e2^T + (w_z - w_x) d d^T. Branch-free, so that
// fusion's per-row loop vectorises: where d runs along `up` (never inside a camera's field of view)
// e2 is zero and both lateral axes get w_x.
DF_INLINE Sym3f ray_information(const Eigen::Vector3f& d, const Eigen::Vector3f& up, float w_x,
                             float w_y, float w_z) {
  const float du = d.dot(up);
  // |.| and the tiny bias instead of a max(): a float max() is a branch the vectoriser refuses.
  const float s2 = std::abs(1.0f - du * du) + 1e-12f;
  const Eigen::Vector3f e2 = (up - du * d) * (1.0f / std::sqrt(s2));
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
// (p_n, L_n), accepted when the fused point lies inside both unit ellipsoids. Writes the fused
// point and information whether or not it accepts (they are meaningless when it does not), without
// a branch: fusion evaluates it for a whole image row at once. merge_measurement() is its public
// face.
DF_INLINE bool merge_rule(const Eigen::Vector3f& p_e, const Sym3f& L_e, const Eigen::Vector3f& p_n,
                       const Sym3f& L_n, Eigen::Vector3f* p_fused, Sym3f* L_fused) {
  const Sym3f L = L_e + L_n;
  Sym3f C;
  const bool invertible = invert(L, &C);
  const Eigen::Vector3f delta = p_n - p_e;
  const Eigen::Vector3f from_e = C * (L_n * delta);  // p' - p_e
  const bool inside_e = mahalanobis2(from_e, L_e) <= 1.0f;
  const bool inside_n = mahalanobis2(Eigen::Vector3f(from_e - delta), L_n) <= 1.0f;  // p' - p_n
  *p_fused = p_e + from_e;
  *L_fused = L;
  return invertible & inside_e & inside_n;
}

// A point's normal after one more measurement: the running mean of the normals of its `merges`
// measurements so far (n_old) and the new one, renormalised. Branch-free, for the row loop.
DF_INLINE Eigen::Vector3f running_mean_normal(float merges, const Eigen::Vector3f& n_old,
                                              const Eigen::Vector3f& n_new) {
  const float w = merges + 1.0f;
  const Eigen::Vector3f n(w * n_old.x() + n_new.x(), w * n_old.y() + n_new.y(),
                          w * n_old.z() + n_new.z());
  const float len2 = n.x() * n.x() + n.y() * n.y() + n.z() * n.z();
  const float s = len2 > 1e-12f ? 1.0f / std::sqrt(len2) : 1.0f;
  return n * s;
}

}  // namespace depthfuse
