// Internal: the per-point arithmetic of the map's deformation (MapDeformation moves points with
// their keyframes, ChunkMerger merges the surfaces that then lie on each other), apart from the
// logic that calls it. Nothing here looks anything up; each reads and writes what it is handed.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

#include "depthfuse/point_arrays.hpp"
#include "fusion_kernels.hpp"
#include "geometry.hpp"

namespace depthfuse {

// A rigid motion in the world frame, in float for the per-point loop: p' = R p + t.
struct RigidMotionF {
  Eigen::Matrix3f R = Eigen::Matrix3f::Identity();
  Eigen::Vector3f t = Eigen::Vector3f::Zero();
};

// R L R^T: an information matrix carried along by the rotation R.
DF_INLINE Sym3f rotate_information(const Eigen::Matrix3f& R, const Sym3f& L) {
  // M = R L, then the upper triangle of M R^T.
  const Eigen::Vector3f r0 = R.row(0), r1 = R.row(1), r2 = R.row(2);
  const Eigen::Vector3f m0 = L * r0, m1 = L * r1, m2 = L * r2;  // rows of R L (L symmetric)
  return {m0.dot(r0), m0.dot(r1), m0.dot(r2), m1.dot(r1), m1.dot(r2), m2.dot(r2)};
}

// Moves point i of `a` by m: its position, its normal and its information matrix.
DF_INLINE void move_point(PointArrays& a, size_t i, const RigidMotionF& m) {
  a.position_m[i] = rotate(m.R, a.position_m[i]) + m.t;
  PointState& s = a.state[i];
  const Eigen::Vector3f n = rotate(m.R, Eigen::Vector3f(s.nx, s.ny, s.nz));
  s.nx = n.x();
  s.ny = n.y();
  s.nz = n.z();
  set_information(&s, rotate_information(m.R, information_of(s)));
}

// How far from a point its ellipsoid (information L) reaches at most: the square root of the
// covariance's trace, which bounds its largest semi-axis. Two points the merge rule accepts lie
// within the sum of their reaches (the fused point lies inside both ellipsoids). Infinite where L
// is singular.
DF_INLINE float reach_m(const PointState& s) {
  float cofactors, det;
  covariance_trace_parts(s, &cofactors, &det);
  if (!(det > 0.0f)) return std::numeric_limits<float>::infinity();
  return std::sqrt(std::max(0.0f, cofactors / det));
}

DF_INLINE uint16_t saturating_add(uint32_t a, uint32_t b) {
  return static_cast<uint16_t>(std::min<uint32_t>(a + b, std::numeric_limits<uint16_t>::max()));
}

// Merges point j of `a` into point i, which takes (p, L), the merge rule's fused point and
// information. Their measurements add (a point's merge count is its measurements less one), and so
// do their violations; normal and colour are their means weighted by measurements, as fusion's
// running means are; the last frame is the newer one's.
DF_INLINE void absorb_point(PointArrays& a, size_t i, size_t j, const Eigen::Vector3f& p,
                            const Sym3f& L) {
  PointState& s = a.state[i];
  const PointState& o = a.state[j];
  const float w_i = static_cast<float>(s.merges) + 1.0f, w_j = static_cast<float>(o.merges) + 1.0f;
  Eigen::Vector3f n(w_i * s.nx + w_j * o.nx, w_i * s.ny + w_j * o.ny, w_i * s.nz + w_j * o.nz);
  const float len = n.norm();
  if (len > 1e-6f) n /= len;
  const float inv = 1.0f / (w_i + w_j);
  s.r = static_cast<uint8_t>((w_i * s.r + w_j * o.r) * inv + 0.5f);
  s.g = static_cast<uint8_t>((w_i * s.g + w_j * o.g) * inv + 0.5f);
  s.b = static_cast<uint8_t>((w_i * s.b + w_j * o.b) * inv + 0.5f);
  s.nx = n.x();
  s.ny = n.y();
  s.nz = n.z();
  s.merges = saturating_add(uint32_t{s.merges} + 1u, o.merges);
  s.violations = saturating_add(s.violations, o.violations);
  s.last_frame = std::max(s.last_frame, o.last_frame);
  set_information(&s, L);
  a.position_m[i] = p;
}

}  // namespace depthfuse
