// Tiny analytic scenes rendered exactly, for tests that must not depend on the synthetic driver.
#pragma once

#include <cmath>

#include "depthfuse/types.hpp"

namespace depthfuse::test {

// A camera at T_world_cam looking at the plane n.x = d (world), rendered without noise.
inline Frame render_plane(const Pose& T_world_cam, const Eigen::Vector3d& n, double d,
                          const CameraIntrinsics& K = CameraIntrinsics::kinect_v2()) {
  Frame f;
  f.intrinsics = K;
  f.depth = DepthImage(K.width, K.height);
  const Eigen::Vector3d o = T_world_cam.translation();
  for (int v = 0; v < K.height; ++v)
    for (int u = 0; u < K.width; ++u) {
      const Eigen::Vector3d ray_c((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
      const Eigen::Vector3d ray_w = T_world_cam.linear() * ray_c;
      const double denom = n.dot(ray_w);
      if (std::abs(denom) < 1e-9) continue;
      const double s = (d - n.dot(o)) / denom;  // ray parameter = depth (ray_c.z == 1)
      if (s > 0) f.depth.at(u, v) = static_cast<float>(s);
    }
  return f;
}

// The inside of a corner: planes x = 0, y = 0, z = 0 seen from `eye` looking at `target`.
inline Pose look_at(const Eigen::Vector3d& eye, const Eigen::Vector3d& target,
                    const Eigen::Vector3d& up_hint = Eigen::Vector3d::UnitZ()) {
  const Eigen::Vector3d z = (target - eye).normalized();
  Eigen::Vector3d x = z.cross(up_hint);
  if (x.norm() < 1e-6) x = z.unitOrthogonal();
  x.normalize();
  const Eigen::Vector3d y = z.cross(x);  // camera y points down when up_hint is up
  Pose T = Pose::Identity();
  T.linear().col(0) = x;
  T.linear().col(1) = y;
  T.linear().col(2) = z;
  T.translation() = eye;
  return T;
}

// One row of the corner (x = 0, y = 0, z = 0, each face extent_m wide) as seen from T_world_cam.
inline void render_corner_row(const Pose& T_world_cam, int v, double extent_m, Frame* f) {
  const CameraIntrinsics& K = f->intrinsics;
  const Eigen::Vector3d o = T_world_cam.translation();
  for (int u = 0; u < K.width; ++u) {
    const Eigen::Vector3d ray_w = T_world_cam.linear() * Eigen::Vector3d((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
    double best = INFINITY;
    for (int a = 0; a < 3; ++a) {
      if (std::abs(ray_w[a]) < 1e-12) continue;
      const double s = -o[a] / ray_w[a];
      if (s <= 0 || s >= best) continue;
      const Eigen::Vector3d p = o + s * ray_w;
      bool inside = true;
      for (int b = 0; b < 3; ++b)
        if (b != a && (p[b] < -1e-9 || p[b] > extent_m)) inside = false;
      if (inside) best = s;
    }
    if (std::isfinite(best)) f->depth.at(u, v) = static_cast<float>(best);
  }
}

inline Frame render_corner(const Pose& T_world_cam,
                           const CameraIntrinsics& K = CameraIntrinsics::kinect_v2(),
                           double extent_m = 3.0) {
  Frame f;
  f.intrinsics = K;
  f.depth = DepthImage(K.width, K.height);
  for (int v = 0; v < K.height; ++v) render_corner_row(T_world_cam, v, extent_m, &f);
  return f;
}

// Frame i taken at i / 30 s, as a live camera's frames are stamped: the motion model predicts
// from the frames' times (IncrementalReconstructor::constant_velocity_prediction).
inline void stamp_at_30hz(std::vector<Frame>* frames) {
  for (size_t i = 0; i < frames->size(); ++i)
    (*frames)[i].utime = static_cast<int64_t>(i) * 1000000 / 30;
}

// The corner as a rolling-shutter camera (K.row_readout_s) moving at v_world_m_s takes it: row v
// when the camera is at T_world_cam moved by v_world_m_s times the row's time from the middle row's.
inline Frame render_corner_rolling(const Pose& T_world_cam, const Eigen::Vector3d& v_world_m_s,
                                   const CameraIntrinsics& K, double extent_m = 3.0) {
  Frame f;
  f.intrinsics = K;
  f.depth = DepthImage(K.width, K.height);
  for (int v = 0; v < K.height; ++v) {
    Pose T_row = T_world_cam;
    T_row.translation() += v_world_m_s * (((v + 0.5) / K.height - 0.5) * K.row_readout_s);
    render_corner_row(T_row, v, extent_m, &f);
  }
  return f;
}

inline double corner_distance(const Eigen::Vector3d& p) {
  return std::min({std::abs(p.x()), std::abs(p.y()), std::abs(p.z())});
}

}  // namespace depthfuse::test
