#include "depthfuse/measurement.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>

#include "geometry.hpp"
#include "parallel.hpp"

namespace depthfuse {

size_t MeasurementImage::valid_count() const {
  size_t n = 0;
  for (uint8_t v : valid) n += v;
  return n;
}

void MeasurementImage::resize(int w, int h) {
  width = w;
  height = h;
  const size_t n = static_cast<size_t>(w) * h;
  for (auto* v : {&x, &y, &z, &nx, &ny, &nz}) v->assign(n, 0.0f);
  valid.assign(n, 0);
}

namespace {

// A row of W pixels whose per-pixel work reaches r columns to either side: edge(u) for the r
// columns at each end (which must check the columns), interior(u) for the rest, in a loop the
// compiler may vectorise (interior must not write what another pixel reads).
template <typename Edge, typename Interior>
DF_INLINE void split_row(int W, int r, Edge&& edge, Interior&& interior) {
  for (int u = 0; u < std::min(r, W); ++u) edge(u);
  DF_IVDEP
  for (int u = r; u < W - r; ++u) interior(u);
  for (int u = std::max(r, W - r); u < W; ++u) edge(u);
}

// The back-projected image's columns, for the normal pass.
struct Columns {
  const float *x, *y, *z;
  const uint8_t* valid;
  float *nx, *ny, *nz;
};

// The normal of pixel i from its neighbours at distance r: il and ir left and right, it and ib
// above and below (has_*: the neighbour is in the image; if not, its index may be any pixel).
// Central differences, one-sided where a neighbour is missing or lies across a depth discontinuity;
// oriented towards the camera (origin); zero where there is none. Branch-free, so that the loop
// over a row's interior vectorises.
DF_INLINE void normal_at(const Columns& c, size_t i, size_t il, size_t ir, size_t it, size_t ib,
                         bool has_l, bool has_r, bool has_t, bool has_b) {
  // Every load first and unconditionally (all four indices are in the image), then selects: a
  // load under a condition would be a branch.
  const float x0 = c.x[i], y0 = c.y[i], z0 = c.z[i];
  const float xl = c.x[il], yl = c.y[il], zl = c.z[il], xr = c.x[ir], yr = c.y[ir], zr = c.z[ir];
  const float xt = c.x[it], yt = c.y[it], zt = c.z[it], xb = c.x[ib], yb = c.y[ib], zb = c.z[ib];
  const float tol = 0.05f * z0 + 0.01f;
  const bool l = has_l & (c.valid[il] != 0) & (std::abs(zl - z0) < tol);
  const bool r = has_r & (c.valid[ir] != 0) & (std::abs(zr - z0) < tol);
  const bool t = has_t & (c.valid[it] != 0) & (std::abs(zt - z0) < tol);
  const bool b = has_b & (c.valid[ib] != 0) & (std::abs(zb - z0) < tol);
  // du = (right or p) - (left or p), dv = (below or p) - (above or p).
  const float dux = (r ? xr : x0) - (l ? xl : x0);
  const float duy = (r ? yr : y0) - (l ? yl : y0);
  const float duz = (r ? zr : z0) - (l ? zl : z0);
  const float dvx = (b ? xb : x0) - (t ? xt : x0);
  const float dvy = (b ? yb : y0) - (t ? yt : y0);
  const float dvz = (b ? zb : z0) - (t ? zt : z0);
  float nx = duy * dvz - duz * dvy, ny = duz * dvx - dux * dvz, nz = dux * dvy - duy * dvx;
  const float len2 = nx * nx + ny * ny + nz * nz;
  const bool ok = (c.valid[i] != 0) & (l | r) & (t | b) & (len2 > 1e-24f);
  const float s = (nx * x0 + ny * y0 + nz * z0 > 0.0f) ? -1.0f : 1.0f;  // towards the camera
  const float scale = ok ? s / std::sqrt(ok ? len2 : 1.0f) : 0.0f;
  c.nx[i] = nx * scale;
  c.ny[i] = ny * scale;
  c.nz[i] = nz * scale;
}

}  // namespace

Status backproject(const Frame& frame, const SensorModelConfig& sensor, const FusionConfig& fusion,
                   MeasurementImage* out) {
  const CameraIntrinsics& K = frame.intrinsics;
  const DepthImage& D = frame.depth;
  if (!K.valid()) return invalid_argument("frame has invalid intrinsics");
  if (D.width != K.width || D.height != K.height ||
      D.depth_m.size() != static_cast<size_t>(D.width) * D.height) {
    return invalid_argument("depth image is " + std::to_string(D.width) + "x" +
                            std::to_string(D.height) + " but the intrinsics say " +
                            std::to_string(K.width) + "x" + std::to_string(K.height));
  }
  if (out->width != D.width || out->height != D.height) out->resize(D.width, D.height);
  out->intrinsics = K;

  const float fx_inv = static_cast<float>(1.0 / K.fx), fy_inv = static_cast<float>(1.0 / K.fy);
  const float cx = static_cast<float>(K.cx), cy = static_cast<float>(K.cy);
  const float zmin = static_cast<float>(sensor.min_depth_m), zmax = static_cast<float>(sensor.max_depth_m);
  const int W = D.width, H = D.height;
  // Each pass works on rows; the two halves of the rows run at once if there are two threads. Every
  // pixel is written by one half only, so the result does not depend on the thread count.
  run_row_halves(fusion.threads, H, [&](int v0, int v1) {
    for (int v = v0; v < v1; ++v) {
      for (int u = 0; u < W; ++u) {
        const size_t i = static_cast<size_t>(v) * W + u;
        const float z = D.depth_m[i];
        const bool ok = std::isfinite(z) && z >= zmin && z <= zmax;
        out->valid[i] = ok;
        out->z[i] = ok ? z : 0.0f;
        out->x[i] = ok ? (u - cx) * z * fx_inv : 0.0f;
        out->y[i] = ok ? (v - cy) * z * fy_inv : 0.0f;
      }
    }
  });

  // Normals by central differences over `r` pixels (normal_at). Columns within r of the left or
  // right edge take the clamped path; the rest of the row runs vectorised.
  const int r = std::min(std::max(1, fusion.normal_radius_px), std::max(1, (W - 1) / 2));
  const Columns cols{out->x.data(),  out->y.data(),  out->z.data(), out->valid.data(),
                     out->nx.data(), out->ny.data(), out->nz.data()};
  run_row_halves(fusion.threads, H, [&](int v0, int v1) {
    for (int v = v0; v < v1; ++v) {
      const size_t row = static_cast<size_t>(v) * W;
      const bool has_t = v - r >= 0, has_b = v + r < H;
      // Rows beyond the image: any row will do, the flags ignore it.
      const size_t row_t = has_t ? row - static_cast<size_t>(r) * W : row;
      const size_t row_b = has_b ? row + static_cast<size_t>(r) * W : row;
      split_row(
          W, r,
          [&](int u) {
            const size_t i = row + u;
            const bool has_l = u - r >= 0, has_r = u + r < W;
            normal_at(cols, i, has_l ? i - r : i, has_r ? i + r : i, row_t + u, row_b + u, has_l,
                      has_r, has_t, has_b);
          },
          [&](int u) {
            const size_t i = row + u;
            normal_at(cols, i, i - r, i + r, row_t + u, row_b + u, true, true, has_t, has_b);
          });
    }
  });
  return Status::ok();
}

namespace {

constexpr int kMaxWindow = 7 * 7;

// Distance from pixel (u, v) to its k-th nearest back-projected neighbour within the window, or
// +inf when fewer than k neighbours exist.
inline float kth_neighbour_distance(const MeasurementImage& m, int u, int v, int k, int r) {
  std::array<float, kMaxWindow> best;  // k smallest squared distances, ascending
  int count = 0;
  const size_t i = static_cast<size_t>(v) * m.width + u;
  const float px = m.x[i], py = m.y[i], pz = m.z[i];
  for (int dv = -r; dv <= r; ++dv) {
    const int vv = v + dv;
    if (vv < 0 || vv >= m.height) continue;
    for (int du = -r; du <= r; ++du) {
      const int uu = u + du;
      if ((du == 0 && dv == 0) || uu < 0 || uu >= m.width) continue;
      const size_t j = static_cast<size_t>(vv) * m.width + uu;
      if (!m.valid[j]) continue;
      const float ex = m.x[j] - px, ey = m.y[j] - py, ez = m.z[j] - pz;
      const float d2 = ex * ex + ey * ey + ez * ez;
      if (count < k) {
        int pos = count++;
        while (pos > 0 && best[pos - 1] > d2) { best[pos] = best[pos - 1]; --pos; }
        best[pos] = d2;
      } else if (d2 < best[k - 1]) {
        int pos = k - 1;
        while (pos > 0 && best[pos - 1] > d2) { best[pos] = best[pos - 1]; --pos; }
        best[pos] = d2;
      }
    }
  }
  return count < k ? std::numeric_limits<float>::infinity() : std::sqrt(best[k - 1]);
}

int clamp_radius(int r) { return std::clamp(r, 1, 3); }

}  // namespace

CameraVelocity camera_velocity(const Pose& T_world_cam_from, const Pose& T_world_cam_to, double dt_s,
                               const Pose& T_world_cam_at) {
  CameraVelocity out;
  if (!(dt_s > 0.0)) return out;
  const Eigen::Matrix3d R_cam_world = T_world_cam_at.linear().transpose();
  const Eigen::AngleAxisd turn(T_world_cam_to.linear() * T_world_cam_from.linear().transpose());
  out.omega_cam_rad_s = R_cam_world * (turn.angle() * turn.axis()) / dt_s;
  out.v_cam_m_s = R_cam_world * (T_world_cam_to.translation() - T_world_cam_from.translation()) / dt_s;
  return out;
}

std::vector<CameraVelocity> camera_velocities(const std::vector<Frame>& frames,
                                              const std::vector<Pose>& T_world_cam) {
  const size_t n = std::min(frames.size(), T_world_cam.size());
  std::vector<CameraVelocity> out(n);
  for (size_t i = 0; i < n && n > 1; ++i) {
    const size_t k = i > 0 ? i - 1 : i, j = i + 1 < n ? i + 1 : i;
    const double dt_s = static_cast<double>(frames[j].utime - frames[k].utime) * 1e-6;
    out[i] = camera_velocity(T_world_cam[k], T_world_cam[j], dt_s, T_world_cam[i]);
  }
  return out;
}

bool undo_rolling_shutter(const Frame& frame, const CameraVelocity& velocity, DepthImage* out) {
  return undo_rolling_shutter(frame, velocity, frame.intrinsics.row_readout_s, out);
}

double row_readout_s(const Frame& frame, const SensorModelConfig& sensor) {
  return frame.intrinsics.row_readout_s > 0.0 ? frame.intrinsics.row_readout_s : sensor.row_readout_s;
}

bool undo_rolling_shutter(const Frame& frame, const CameraVelocity& velocity, double readout_s,
                          DepthImage* out) {
  const CameraIntrinsics& K = frame.intrinsics;
  const DepthImage& D = frame.depth;
  if (!(readout_s > 0.0) || !K.valid() || D.width != K.width || D.height != K.height ||
      (velocity.omega_cam_rad_s.isZero() && velocity.v_cam_m_s.isZero()))
    return false;
  const int W = D.width, H = D.height;
  // A point seen at row v, taken dt = (row time - middle row's time) later, is, in the camera at
  // the middle row's time, p + dt (omega x p + v) (first order: a few millimetres).
  auto at_mid_time = [&](int u, int v, double z) {
    const Eigen::Vector3d p((u - K.cx) / K.fx * z, (v - K.cy) / K.fy * z, z);
    const double dt_s = ((v + 0.5) / H - 0.5) * readout_s;
    return Eigen::Vector3d(p + dt_s * (velocity.omega_cam_rad_s.cross(p) + velocity.v_cam_m_s));
  };
  DepthImage warped(W, H);
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      // The source pixel: this pixel moved back by the shift of its own point (the shift varies
      // slowly over the image, so the source's is nearly the same).
      int us = u, vs = v;
      const float z = D.at(u, v);
      if (std::isfinite(z) && z > 0.0f) {
        const Eigen::Vector3d p = at_mid_time(u, v, z);
        us = static_cast<int>(std::lround(2.0 * u - (K.fx * p.x() / p.z() + K.cx)));
        vs = static_cast<int>(std::lround(2.0 * v - (K.fy * p.y() / p.z() + K.cy)));
      }
      if (us < 0 || us >= W || vs < 0 || vs >= H) continue;
      const float zs = D.at(us, vs);
      if (!(std::isfinite(zs) && zs > 0.0f)) continue;
      warped.at(u, v) = static_cast<float>(at_mid_time(us, vs, zs).z());
    }
  }
  *out = std::move(warped);
  return true;
}

double reference_knn_distance_per_m(const CameraIntrinsics& K, int neighbour_rank,
                                    int window_radius_px) {
  // A constant depth map at 1 m, back-projected; average the k-th neighbour distance over a grid
  // of sample pixels (the image border excluded, where the window is cut).
  const int r = clamp_radius(window_radius_px);
  const int k = std::clamp(neighbour_rank, 1, (2 * r + 1) * (2 * r + 1) - 1);
  MeasurementImage plane;
  plane.resize(K.width, K.height);
  for (int v = 0; v < K.height; ++v)
    for (int u = 0; u < K.width; ++u) {
      const size_t i = static_cast<size_t>(v) * K.width + u;
      plane.x[i] = static_cast<float>((u - K.cx) / K.fx);
      plane.y[i] = static_cast<float>((v - K.cy) / K.fy);
      plane.z[i] = 1.0f;
      plane.valid[i] = 1;
    }
  double sum = 0;
  size_t n = 0;
  for (int v = r; v < K.height - r; v += 7)
    for (int u = r; u < K.width - r; u += 7) {
      sum += kth_neighbour_distance(plane, u, v, k, r);
      ++n;
    }
  return n ? sum / n : 0.0;
}

namespace {

// The pre-filter's count over image rows: marks each valid pixel with fewer than k neighbours
// (in the (2R + 1)^2 window) within per_m * z of it.
struct PrefilterPass {
  const float *X, *Y, *Z;
  const uint8_t* valid;
  uint8_t* marks;
  int W, H, k;
  float per_m;

  // Neighbours of pixel (u, v) within the limit. kCheckColumns: the window may leave the image
  // sideways (the R columns at each edge). Rows outside the image count nothing (has_row).
  // Branch-free: every index is in the image (clamped to the centre where the neighbour is not).
  template <int R, bool kCheckColumns>
  DF_INLINE int within(int u, size_t i, const size_t* row, const bool* has_row) const {
    const float limit = per_m * Z[i];
    const float limit2 = limit * limit;
    const float px = X[i], py = Y[i], pz = Z[i];
    int count = 0;
    DF_UNROLL(7)
    for (int dv = -R; dv <= R; ++dv) {
      DF_UNROLL(7)
      for (int du = -R; du <= R; ++du) {
        if (du == 0 && dv == 0) continue;  // a constant: unrolled away
        bool in = has_row[dv + R];
        size_t j = row[dv + R] + u + du;
        if (kCheckColumns) {
          in = in && u + du >= 0 && u + du < W;
          j = in ? j : i;
        }
        const float ex = X[j] - px, ey = Y[j] - py, ez = Z[j] - pz;
        count += in & (valid[j] != 0) & (ex * ex + ey * ey + ez * ez <= limit2);
      }
    }
    return count;
  }

  template <int R>
  DF_VECTOR_CLONES size_t rows(int v0, int v1) const {
    // Locals, not members, in the loops: a store to the byte-sized marks may alias any member,
    // and the compiler would reload them (and could not count the iterations).
    const PrefilterPass p = *this;
    const int W = p.W, H = p.H, k = p.k;
    const uint8_t* valid = p.valid;
    uint8_t* marks = p.marks;
    size_t removed = 0;
    for (int v = v0; v < v1; ++v) {
      const size_t centre = static_cast<size_t>(v) * W;
      size_t row[2 * R + 1];
      bool has_row[2 * R + 1];
      for (int dv = -R; dv <= R; ++dv) {
        has_row[dv + R] = v + dv >= 0 && v + dv < H;
        row[dv + R] = has_row[dv + R] ? centre + static_cast<ptrdiff_t>(dv) * W : centre;
      }
      split_row(
          W, R,
          [&](int u) {
            const size_t i = centre + u;
            marks[i] = valid[i] && p.within<R, true>(u, i, row, has_row) < k;
          },
          [&](int u) {
            const size_t i = centre + u;
            marks[i] = (valid[i] != 0) & (p.within<R, false>(u, i, row, has_row) < k);
          });
      for (int u = 0; u < W; ++u) removed += marks[centre + u];
    }
    return removed;
  }
};

}  // namespace

size_t prefilter(const PrefilterConfig& config, MeasurementImage* m, int threads) {
  if (!config.enabled || m->pixel_count() == 0) return 0;
  const int r = clamp_radius(config.window_radius_px);
  const int k = std::clamp(config.neighbour_rank, 1, (2 * r + 1) * (2 * r + 1) - 1);
  // d_r(z) depends only on the intrinsics and the window: compute it once per camera.
  struct Cached {
    CameraIntrinsics K;
    int k = 0, r = 0;
    double per_m = 0;
  };
  thread_local Cached cache;
  const CameraIntrinsics& K = m->intrinsics;
  if (cache.k != k || cache.r != r || cache.K.width != K.width || cache.K.height != K.height ||
      cache.K.fx != K.fx || cache.K.fy != K.fy || cache.K.cx != K.cx || cache.K.cy != K.cy) {
    cache = {K, k, r, reference_knn_distance_per_m(K, k, r)};
  }
  const float per_m = static_cast<float>(config.gamma * cache.per_m);

  // d_k > gamma d_r(z) exactly when fewer than k neighbours lie within gamma d_r(z): count them
  // instead of sorting distances. Decide on the unfiltered map first, then remove: the test of
  // one pixel must not depend on which of its neighbours were removed before it.
  // The mark buffer is reached through a plain pointer: the second thread must mark this thread's
  // buffer, not a thread_local of its own.
  thread_local std::vector<uint8_t> remove;
  remove.assign(m->pixel_count(), 0);
  const PrefilterPass pass{m->x.data(), m->y.data(), m->z.data(), m->valid.data(), remove.data(),
                           m->width, m->height, k, per_m};
  // The two halves of the rows at once if there are two threads: each only reads the map and
  // marks its own pixels.
  std::atomic<size_t> removed_total{0};
  run_row_halves(threads, m->height, [&](int v0, int v1) {
    size_t removed = 0;
    switch (r) {  // the window's radius as a constant: the neighbour loops unroll
      case 1: removed = pass.rows<1>(v0, v1); break;
      case 2: removed = pass.rows<2>(v0, v1); break;
      default: removed = pass.rows<3>(v0, v1); break;
    }
    removed_total += removed;
  });
  // A select, not a conditional store, and the count read once (a byte store may alias the
  // vector's size, which would then be read again from thread-local storage every pixel): it
  // then vectorises.
  const uint8_t* const marks = remove.data();
  uint8_t* const valid = m->valid.data();
  const size_t n = remove.size();
  DF_IVDEP
  for (size_t i = 0; i < n; ++i) valid[i] = marks[i] ? uint8_t{0} : valid[i];
  return removed_total;
}

}  // namespace depthfuse
