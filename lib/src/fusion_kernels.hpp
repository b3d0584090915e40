// Internal: fusion's kernels, apart from the loop that calls them (fusion.cpp's FrameFusion): the
// vectorised passes over an image row (fusion_kernels.cpp, each compiled for AVX2 too:
// DF_VECTOR_CLONES on its definition, where GCC emits the clones and the symbol that picks one)
// and the per-point arithmetic the loop over pixels inlines. None of them looks anything up in
// the map; each reads and writes only what it is handed.
#pragma once

#include <cstdint>
#include <limits>

#include "depthfuse/point_arrays.hpp"
#include "depthfuse/sensor_model.hpp"
#include "fusion_columns.hpp"
#include "geometry.hpp"

namespace depthfuse {

// The frame's camera in the world: rotation and translation of T_world_cam, and its y axis (up),
// which fixes the lateral axes of the measurements' ellipsoids (ray_information()).
struct CameraInWorld {
  Eigen::Matrix3f R;
  Eigen::Vector3f t, up;
};

// The first pass over an image row of `width` pixels, valid or not: each measurement (camera-frame
// points p_cam and normals n_cam) in the world frame, its range and information, and its merge
// with the candidate rendered at its own pixel (c, the row's candidates as they stand) into `row`.
void prepare_row(Vec3Columns<const float> p_cam, Vec3Columns<const float> n_cam,
                 const CameraInWorld& camera, const SensorModel& model, const CandidateColumns& c,
                 int width, const RowColumns& row);

// The second with a 3x3 window, after prepare_row(), for the pixels 1 to width - 2 of an image row
// that is neither the first nor the last: RowColumns::window_px, chosen in the window's row-major
// order like a search pixel by pixel. `c` holds the candidates of the whole image (from pixel 0),
// first_px is the row's first pixel.
void select_window_3x3(const CandidateColumns& c, size_t first_px, int width,
                       const RowColumns& row);

// A candidate in the window, at pixel `px` with world position c, against the best so far for the
// measurement at p_w with information L_n: keeps the nearer in the measurement's metric, the first
// on ties. Without branches.
DF_INLINE void consider_candidate(bool has, int32_t px, const Eigen::Vector3f& c,
                                  const Eigen::Vector3f& p_w, const Sym3f& L_n, float* best_d2,
                                  int32_t* best_px) {
  const float d2 = mahalanobis2(Eigen::Vector3f(c - p_w), L_n);
  const bool better = has & (d2 < *best_d2);
  *best_d2 = better ? d2 : *best_d2;
  *best_px = better ? px : *best_px;
}

DF_INLINE uint16_t saturating_increment(uint16_t v) {
  return v == std::numeric_limits<uint16_t>::max() ? v : static_cast<uint16_t>(v + 1);
}

DF_INLINE void set_information(PointState* s, const Sym3f& L) {
  s->info_xx = L.xx; s->info_xy = L.xy; s->info_xz = L.xz;
  s->info_yy = L.yy; s->info_yz = L.yz; s->info_zz = L.zz;
}

DF_INLINE Sym3f information_of(const PointState& s) {
  return {s.info_xx, s.info_xy, s.info_xz, s.info_yy, s.info_yz, s.info_zz};
}

// Refines existing point i of `a` with a measurement: the merge rule's position p and information
// L, and n, the running mean of the normals (running_mean_normal()); rgb may be null.
DF_INLINE void refine_point(PointArrays& a, size_t i, const Eigen::Vector3f& p, const Sym3f& L,
                            const Eigen::Vector3f& n, const uint8_t* rgb, uint32_t frame_id) {
  a.position_m[i] = p;
  PointState& s = a.state[i];
  set_information(&s, L);
  // Colour: the running mean over all measurements of the point, like the normal.
  const float w = static_cast<float>(s.merges) + 1.0f;
  s.nx = n.x();
  s.ny = n.y();
  s.nz = n.z();
  if (rgb) {
    const float inv = 1.0f / (w + 1.0f);
    s.r = static_cast<uint8_t>((w * s.r + rgb[0]) * inv + 0.5f);
    s.g = static_cast<uint8_t>((w * s.g + rgb[1]) * inv + 0.5f);
    s.b = static_cast<uint8_t>((w * s.b + rgb[2]) * inv + 0.5f);
  }
  s.merges = saturating_increment(s.merges);
  s.last_frame = frame_id;
}

// A new point's state from its first measurement: information L, normal n, colour rgb (may be
// null).
DF_INLINE PointState new_point_state(const Sym3f& L, const Eigen::Vector3f& n, const uint8_t* rgb,
                                     uint32_t frame_id) {
  PointState st{};
  set_information(&st, L);
  st.nx = n.x();
  st.ny = n.y();
  st.nz = n.z();
  if (rgb) { st.r = rgb[0]; st.g = rgb[1]; st.b = rgb[2]; }
  st.last_frame = frame_id;
  return st;
}

// Whether a camera at t that measured p_n (normal n_n, at range_n from it) saw through the point
// p_e (normal n_e) in front of it: both face the camera, and their ranges differ by less than
// `fraction` of the measurement's (the paper's eq. 2-3).
DF_INLINE bool sees_through(const Eigen::Vector3f& t, const Eigen::Vector3f& p_e,
                            const Eigen::Vector3f& n_e, const Eigen::Vector3f& p_n,
                            const Eigen::Vector3f& n_n, float range_n, float fraction) {
  const float s_e = (p_e - t).norm();
  const bool facing_e = n_e.dot(t - p_e) > 0.0f;
  const bool facing_n = n_n.dot(t - p_n) > 0.0f;
  return facing_e && facing_n && std::abs(s_e - range_n) < fraction * range_n;
}

}  // namespace depthfuse
