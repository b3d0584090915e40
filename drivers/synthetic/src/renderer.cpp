// Depth and colour rendering by raycasting, then the time-of-flight noise of NoiseConfig.
//
// Two passes over the image: (1) one ray per pixel gives the exact depth, the incidence angle, the
// multipath bias and the colour; (2) the noise, which needs the exact depth of the neighbours
// (flying pixels). Scratch buffers are per thread and reused, so a frame allocates nothing but its
// output.
#include "depthfuse/synthetic/renderer.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "random.hpp"

namespace depthfuse::synthetic {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

constexpr int kTilePx = 16;  // frustum culling granularity

// Primitives of one view: id, a lower bound of their depth, and the corners of their bounds in the
// camera frame (8 per bounded primitive; none for unbounded ones).
struct ViewList {
  std::vector<int> ids;
  std::vector<double> zmin;
  std::vector<Eigen::Vector3d> corners;
  std::vector<char> bounded;

  // Keeps the primitives whose bounds, grown by `grow_m`, reach in front of the camera and nearer
  // than max_z.
  void collect(const std::vector<Eigen::AlignedBox3d>& bounds, const Eigen::Matrix3d& Rt,
               const Eigen::Vector3d& origin, double grow_m, double max_z) {
    ids.clear();
    zmin.clear();
    corners.clear();
    bounded.clear();
    for (size_t p = 0; p < bounds.size(); ++p) {
      const Eigen::AlignedBox3d& b = bounds[p];
      const bool finite = b.min().allFinite() && b.max().allFinite();
      double z_lo = 0.0;
      if (finite) {
        const Eigen::Vector3d lo = b.min().array() - grow_m, hi = b.max().array() + grow_m;
        Eigen::Vector3d c[8];
        double z_hi = -std::numeric_limits<double>::infinity();
        z_lo = std::numeric_limits<double>::infinity();
        for (int k = 0; k < 8; ++k) {
          const Eigen::Vector3d w((k & 1) ? hi.x() : lo.x(), (k & 2) ? hi.y() : lo.y(),
                                  (k & 4) ? hi.z() : lo.z());
          c[k] = Rt * (w - origin);
          z_lo = std::min(z_lo, c[k].z());
          z_hi = std::max(z_hi, c[k].z());
        }
        if (z_hi <= 0.0 || z_lo > max_z) continue;
        z_lo = std::max(z_lo, 0.0);
        corners.insert(corners.end(), c, c + 8);
      }
      ids.push_back(static_cast<int>(p));
      zmin.push_back(z_lo);
      bounded.push_back(finite ? 1 : 0);
    }
  }
};

struct Scratch {
  std::vector<float> exact_m;  // exact depth, 0 = none
  std::vector<float> cos_incidence;
  std::vector<float> mpi_bias_m;  // depth (z) bias
  // Primitives that may be visible in this view, and those that may be near a visible point (for
  // the multipath model: bounds grown by its range).
  ViewList visible;
  ViewList near_visible;
  // Per tile: the visible ones sorted by depth bound, and the near ones.
  std::vector<int> tile_ids;
  std::vector<double> tile_zmin;
  std::vector<int> tile_near_ids;
  Scene::ViewCache view;
};

// floor() for the texture without a libm call.
inline long floor_to_long(double x) {
  const long i = static_cast<long>(x);
  return i - (x < static_cast<double>(i) ? 1 : 0);
}

// True when the convex hull of the 8 camera-frame corners lies entirely outside the frustum of
// rays (a, b, 1) with a in [a0, a1], b in [b0, b1].
inline bool outside_tile(const Eigen::Vector3d* c, double a0, double a1, double b0, double b1) {
  bool all = true;
  for (int k = 0; k < 8 && all; ++k) all = c[k].x() < a0 * c[k].z();
  if (all) return true;
  all = true;
  for (int k = 0; k < 8 && all; ++k) all = c[k].x() > a1 * c[k].z();
  if (all) return true;
  all = true;
  for (int k = 0; k < 8 && all; ++k) all = c[k].y() < b0 * c[k].z();
  if (all) return true;
  all = true;
  for (int k = 0; k < 8 && all; ++k) all = c[k].y() > b1 * c[k].z();
  return all;
}

Scratch& thread_scratch(size_t n) {
  thread_local Scratch s;
  if (s.exact_m.size() != n) {
    s.exact_m.assign(n, 0.0f);
    s.cos_incidence.assign(n, 0.0f);
    s.mpi_bias_m.assign(n, 0.0f);
  }
  return s;
}

// acos on [0, 1] to 7e-5 rad (Abramowitz & Stegun 4.4.45): the incidence angle of every pixel,
// without the cost of std::acos.
inline double fast_acos01(double x) {
  x = x < 0.0 ? 0.0 : (x > 1.0 ? 1.0 : x);
  return std::sqrt(1.0 - x) * (1.5707288 + x * (-0.2121144 + x * (0.0742610 - 0.0187293 * x)));
}

// albedo * factor for factor in [0, 1].
inline uint8_t shade(uint8_t albedo, double factor) {
  return static_cast<uint8_t>(albedo * factor + 0.5);
}

}  // namespace

Status RendererConfig::validate() const {
  if (!intrinsics.valid())
    return invalid_argument("intrinsics must have a positive size and focal lengths");
  if (!(min_depth_m > 0.0) || !(max_depth_m > min_depth_m) || !std::isfinite(max_depth_m))
    return invalid_argument("the sensor range must satisfy 0 < min_depth_m < max_depth_m, got [" +
                            std::to_string(min_depth_m) + ", " + std::to_string(max_depth_m) + "]");
  return noise.validate();
}

DepthRenderer::DepthRenderer(std::shared_ptr<const Scene> scene, RendererConfig config)
    : scene_(std::move(scene)), config_(std::move(config)) {
  if (!scene_) return;
  // Checker squares per metre, once: a division per pixel costs a noticeable share of a frame.
  for (const Primitive& p : scene_->primitives())
    checker_per_m_.push_back(p.checker_m > 0.0 ? 1.0 / p.checker_m : 0.0);
}

void DepthRenderer::render(const Pose& T_world_cam, uint64_t noise_key, bool with_noise,
                           DepthImage* depth, ColorImage* color) const {
  const CameraIntrinsics& K = config_.intrinsics;
  const NoiseConfig& nc = config_.noise;
  const int W = K.width, H = K.height;
  const size_t n = static_cast<size_t>(W) * static_cast<size_t>(H);

  depth->width = W;
  depth->height = H;
  depth->depth_m.assign(n, 0.0f);
  if (color) {
    color->width = W;
    color->height = H;
    color->rgb.assign(3 * n, 0);
  }
  if (!scene_) return;

  const bool noisy = with_noise && nc.enabled;
  const bool want_mpi = noisy && nc.mpi_enabled && nc.mpi_max_bias_m > 0.0 && nc.mpi_range_m > 0.0;
  Scratch& scratch = thread_scratch(n);
  float* exact = noisy ? scratch.exact_m.data() : depth->depth_m.data();
  float* cos_inc = scratch.cos_incidence.data();
  float* mpi = scratch.mpi_bias_m.data();

  const Eigen::Matrix3d R = T_world_cam.linear();
  const Eigen::Vector3d origin = T_world_cam.translation();
  const Eigen::Vector3d rx = R.col(0) / K.fx;
  const double min_z = config_.min_depth_m, max_z = config_.max_depth_m;

  // Which primitives can be seen at all: in front of the camera and nearer than the range.
  const Eigen::Matrix3d Rt = R.transpose();
  scratch.visible.collect(scene_->primitive_bounds(), Rt, origin, 0.0, max_z);
  scene_->prepare_view(origin, &scratch.view);
  if (want_mpi)
    scratch.near_visible.collect(scene_->primitive_bounds(), Rt, origin, nc.mpi_range_m, max_z);

  // Pass 1: exact geometry, tile by tile against the primitives that overlap the tile's frustum,
  // nearest first. The camera ray of pixel (u, v) is ((u-cx)/fx, (v-cy)/fy, 1), rotated to the
  // world: with that scale the hit parameter t is the depth z itself.
  RayHit hit;
  for (int tv = 0; tv < H; tv += kTilePx) {
    const int v_end = std::min(H, tv + kTilePx);
    for (int tu = 0; tu < W; tu += kTilePx) {
      const int u_end = std::min(W, tu + kTilePx);
      const double a0 = (tu - K.cx) / K.fx, a1 = (u_end - 1 - K.cx) / K.fx;
      const double b0 = (tv - K.cy) / K.fy, b1 = (v_end - 1 - K.cy) / K.fy;
      scratch.tile_ids.clear();
      scratch.tile_zmin.clear();
      const ViewList& vis = scratch.visible;
      for (size_t k = 0, corner_index = 0; k < vis.ids.size(); ++k) {
        if (vis.bounded[k]) {
          const Eigen::Vector3d* c = &vis.corners[corner_index];
          corner_index += 8;
          if (outside_tile(c, a0, a1, b0, b1)) continue;
        }
        // Insertion keeps the list sorted by depth bound (lists are short).
        const double z = vis.zmin[k];
        size_t pos = scratch.tile_ids.size();
        scratch.tile_ids.push_back(0);
        scratch.tile_zmin.push_back(0.0);
        while (pos > 0 && scratch.tile_zmin[pos - 1] > z) {
          scratch.tile_ids[pos] = scratch.tile_ids[pos - 1];
          scratch.tile_zmin[pos] = scratch.tile_zmin[pos - 1];
          --pos;
        }
        scratch.tile_ids[pos] = vis.ids[k];
        scratch.tile_zmin[pos] = z;
      }
      scratch.tile_near_ids.clear();
      if (want_mpi) {
        const ViewList& near = scratch.near_visible;
        for (size_t k = 0, corner_index = 0; k < near.ids.size(); ++k) {
          if (near.bounded[k]) {
            const Eigen::Vector3d* c = &near.corners[corner_index];
            corner_index += 8;
            if (outside_tile(c, a0, a1, b0, b1)) continue;
          }
          scratch.tile_near_ids.push_back(near.ids[k]);
        }
      }
      const int* ids = scratch.tile_ids.data();
      const double* zlow = scratch.tile_zmin.data();
      const size_t count = scratch.tile_ids.size();

      for (int v = tv; v < v_end; ++v) {
        const Eigen::Vector3d row = R.col(1) * ((v - K.cy) / K.fy) + R.col(2) - rx * K.cx;
        for (int u = tu; u < u_end; ++u) {
          const size_t i = static_cast<size_t>(v) * W + u;
          const Eigen::Vector3d d = row + rx * u;
          exact[i] = 0.0f;
          cos_inc[i] = 0.0f;
          mpi[i] = 0.0f;
          if (count == 0 ||
              !scene_->raycast_candidates(scratch.view, d, ids, zlow, count, max_z, &hit))
            continue;
          const double inv_len = 1.0 / d.norm();
          const double c = std::fabs(hit.normal_w.dot(d)) * inv_len;
          if (color) {
            const Primitive& prim = scene_->primitives()[static_cast<size_t>(hit.primitive)];
            double f = 0.3 + 0.7 * c;
            const double per_m = checker_per_m_[static_cast<size_t>(hit.primitive)];
            if (per_m > 0.0) {
              const long cu = floor_to_long(hit.uv_m.x() * per_m);
              const long cv = floor_to_long(hit.uv_m.y() * per_m);
              f = (((cu + cv) & 1) ? 1.0 : 0.7) * f;
            }
            uint8_t* px = &color->rgb[3 * i];
            px[0] = shade(prim.color_rgb[0], f);
            px[1] = shade(prim.color_rgb[1], f);
            px[2] = shade(prim.color_rgb[2], f);
          }
          if (hit.t < min_z) continue;  // too near: no return, and it hides what is behind
          exact[i] = static_cast<float>(hit.t);
          cos_inc[i] = static_cast<float>(c);
          if (want_mpi) {
            const Eigen::Vector3d p = origin + hit.t * d;
            const double edge_m = scene_->concave_edge_distance_m(
                p, hit.normal_w, hit.primitive, hit.face, nc.mpi_range_m,
                scratch.tile_near_ids.data(), scratch.tile_near_ids.size());
            // The bias lengthens the range; the depth grows by bias * z / range = bias / |d|.
            mpi[i] = static_cast<float>(mpi_bias_m(nc, edge_m) * inv_len);
          }
        }
      }
    }
  }
  if (!noisy) return;

  // Pass 2: noise. Every random draw is a hash of (noise_key, pixel): order-independent.
  const double max_theta = nc.axial_max_incidence_deg * kDeg;
  const double grazing_start = nc.dropout_grazing_start_deg * kDeg;
  const double far_span = std::max(1e-9, max_z - nc.dropout_far_start_m);
  float* out = depth->depth_m.data();
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      const size_t i = static_cast<size_t>(v) * W + u;
      const double z0 = exact[i];
      if (z0 <= 0.0) continue;
      const uint64_t h1 = detail::mix64(noise_key + 2 * i);
      const uint64_t h2 = detail::mix64(noise_key + 2 * i + 1);
      const double theta = fast_acos01(cos_inc[i]);

      if (nc.dropout_enabled) {
        double p = nc.dropout_probability;
        if (theta > grazing_start) {
          const double g = (theta - grazing_start) / (0.5 * kPi - grazing_start);
          p += g * g;
        }
        if (z0 > nc.dropout_far_start_m)
          p += nc.dropout_far_probability * (z0 - nc.dropout_far_start_m) / far_span;
        if (detail::uniform21(h2, 0) < p) continue;
      }
      if (nc.outlier_enabled && detail::uniform21(h2, 21) < nc.outlier_probability) {
        out[i] = static_cast<float>(
            min_z + (max_z - min_z) * detail::uniform01(detail::mix64(h1 ^ 0x5bd1e995ull)));
        continue;
      }

      double z = z0;
      if (nc.flying_enabled && detail::uniform21(h2, 42) < nc.flying_probability) {
        double lo = z0, hi = z0;
        for (int dv = -1; dv <= 1; ++dv) {
          const int vv = v + dv;
          if (vv < 0 || vv >= H) continue;
          for (int du = -1; du <= 1; ++du) {
            const int uu = u + du;
            if (uu < 0 || uu >= W) continue;
            const float zn = exact[static_cast<size_t>(vv) * W + uu];
            if (zn <= 0.0f) continue;
            lo = std::min(lo, static_cast<double>(zn));
            hi = std::max(hi, static_cast<double>(zn));
          }
        }
        if (hi - lo > std::max(nc.flying_min_jump_m, nc.flying_min_jump_fraction * lo))
          z = lo + (hi - lo) * detail::uniform01(detail::mix64(h2 ^ 0x27d4eb2f165667c5ull));
      }
      if (want_mpi) z += mpi[i];
      if (nc.axial_enabled)
        z += detail::fast_gaussian(h1) * nc.axial_scale *
             fankhauser_axial_sigma_m(z0, theta, max_theta);
      if (z < min_z || z > max_z) continue;
      out[i] = static_cast<float>(z);
    }
  }
}

}  // namespace depthfuse::synthetic
