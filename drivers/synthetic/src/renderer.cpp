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

namespace {

// The tile's candidates from the view's lists: the visible primitives whose bounds reach into the
// tile's frustum of rays (a, b, 1), a in [a0, a1], b in [b0, b1], sorted by depth bound, and (for
// the multipath model) the near-visible ones.
void select_tile_primitives(double a0, double a1, double b0, double b1, bool want_mpi,
                            Scratch* scratch) {
  scratch->tile_ids.clear();
  scratch->tile_zmin.clear();
  const ViewList& vis = scratch->visible;
  for (size_t k = 0, corner_index = 0; k < vis.ids.size(); ++k) {
    if (vis.bounded[k]) {
      const Eigen::Vector3d* c = &vis.corners[corner_index];
      corner_index += 8;
      if (outside_tile(c, a0, a1, b0, b1)) continue;
    }
    // Insertion keeps the list sorted by depth bound (lists are short).
    const double z = vis.zmin[k];
    size_t pos = scratch->tile_ids.size();
    scratch->tile_ids.push_back(0);
    scratch->tile_zmin.push_back(0.0);
    while (pos > 0 && scratch->tile_zmin[pos - 1] > z) {
      scratch->tile_ids[pos] = scratch->tile_ids[pos - 1];
      scratch->tile_zmin[pos] = scratch->tile_zmin[pos - 1];
      --pos;
    }
    scratch->tile_ids[pos] = vis.ids[k];
    scratch->tile_zmin[pos] = z;
  }
  scratch->tile_near_ids.clear();
  if (!want_mpi) return;
  const ViewList& near = scratch->near_visible;
  for (size_t k = 0, corner_index = 0; k < near.ids.size(); ++k) {
    if (near.bounded[k]) {
      const Eigen::Vector3d* c = &near.corners[corner_index];
      corner_index += 8;
      if (outside_tile(c, a0, a1, b0, b1)) continue;
    }
    scratch->tile_near_ids.push_back(near.ids[k]);
  }
}

// The scene's light: from above and a little to one side, the same for every view.
const Eigen::Vector3d kLightDirectionW = Eigen::Vector3d(0.3, 0.2, 1.0).normalized();

// A hit's colour: the primitive's, in its checker texture (squares per metre, 0: plain), shaded as
// a matt surface under kLightDirectionW and an even ambient light. The shade depends on the
// surface alone, not on where the camera is: a real room's walls do not brighten as the camera
// faces them, and tracking's photometric term, which compares a point's brightness across views,
// assumes they do not.
inline void shade_pixel(const Primitive& prim, double checker_per_m, const RayHit& hit,
                        uint8_t* px) {
  double f = 0.55 + 0.45 * hit.normal_w.dot(kLightDirectionW);
  if (checker_per_m > 0.0) {
    const long cu = floor_to_long(hit.uv_m.x() * checker_per_m);
    const long cv = floor_to_long(hit.uv_m.y() * checker_per_m);
    f = (((cu + cv) & 1) ? 1.0 : 0.7) * f;
  }
  px[0] = shade(prim.color_rgb[0], f);
  px[1] = shade(prim.color_rgb[1], f);
  px[2] = shade(prim.color_rgb[2], f);
}

// Pass 1: exact geometry, tile by tile against the primitives that overlap the tile's frustum,
// nearest first. The camera ray of pixel (u, v) is ((u-cx)/fx, (v-cy)/fy, 1), rotated to the
// world: with that scale the hit parameter t is the depth z itself. Per pixel: the exact depth
// (0: none), the incidence angle's cosine and the multipath bias (when wanted), and the colour.
class GeometryPass {
 public:
  GeometryPass(const Scene& scene, const std::vector<double>& checker_per_m,
               const RendererConfig& config, const Pose& T_world_cam, bool want_mpi)
      : scene_(scene),
        checker_per_m_(checker_per_m),
        K_(config.intrinsics),
        nc_(config.noise),
        R_(T_world_cam.linear()),
        origin_(T_world_cam.translation()),
        rx_(R_.col(0) / K_.fx),
        min_z_(config.min_depth_m),
        max_z_(config.max_depth_m),
        want_mpi_(want_mpi) {}

  void run(Scratch* scratch, float* exact, float* cos_inc, float* mpi, ColorImage* color) const {
    // Which primitives can be seen at all: in front of the camera and nearer than the range.
    const Eigen::Matrix3d Rt = R_.transpose();
    scratch->visible.collect(scene_.primitive_bounds(), Rt, origin_, 0.0, max_z_);
    scene_.prepare_view(origin_, &scratch->view);
    if (want_mpi_)
      scratch->near_visible.collect(scene_.primitive_bounds(), Rt, origin_, nc_.mpi_range_m, max_z_);
    const int W = K_.width, H = K_.height;
    RayHit hit;
    for (int tv = 0; tv < H; tv += kTilePx) {
      const int v_end = std::min(H, tv + kTilePx);
      for (int tu = 0; tu < W; tu += kTilePx) {
        const int u_end = std::min(W, tu + kTilePx);
        const double a0 = (tu - K_.cx) / K_.fx, a1 = (u_end - 1 - K_.cx) / K_.fx;
        const double b0 = (tv - K_.cy) / K_.fy, b1 = (v_end - 1 - K_.cy) / K_.fy;
        select_tile_primitives(a0, a1, b0, b1, want_mpi_, scratch);
        for (int v = tv; v < v_end; ++v) {
          const Eigen::Vector3d row = R_.col(1) * ((v - K_.cy) / K_.fy) + R_.col(2) - rx_ * K_.cx;
          for (int u = tu; u < u_end; ++u)
            pixel(u, v, row, *scratch, &hit, exact, cos_inc, mpi, color);
        }
      }
    }
  }

 private:
  // Pixel (u, v) of a row whose rays are row + rx_ * u.
  inline void pixel(int u, int v, const Eigen::Vector3d& row, const Scratch& scratch, RayHit* hit,
                    float* exact, float* cos_inc, float* mpi, ColorImage* color) const {
    const size_t i = static_cast<size_t>(v) * K_.width + u;
    const Eigen::Vector3d d = row + rx_ * u;
    exact[i] = 0.0f;
    cos_inc[i] = 0.0f;
    mpi[i] = 0.0f;
    const size_t count = scratch.tile_ids.size();
    if (count == 0 || !scene_.raycast_candidates(scratch.view, d, scratch.tile_ids.data(),
                                                 scratch.tile_zmin.data(), count, max_z_, hit))
      return;
    const double inv_len = 1.0 / d.norm();
    const double c = std::fabs(hit->normal_w.dot(d)) * inv_len;
    if (color) {
      const auto prim = static_cast<size_t>(hit->primitive);
      shade_pixel(scene_.primitives()[prim], checker_per_m_[prim], *hit, &color->rgb[3 * i]);
    }
    if (hit->t < min_z_) return;  // too near: no return, and it hides what is behind
    exact[i] = static_cast<float>(hit->t);
    cos_inc[i] = static_cast<float>(c);
    if (want_mpi_) {
      const Eigen::Vector3d p = origin_ + hit->t * d;
      const double edge_m = scene_.concave_edge_distance_m(
          p, hit->normal_w, hit->primitive, hit->face, nc_.mpi_range_m, scratch.tile_near_ids.data(),
          scratch.tile_near_ids.size());
      // The bias lengthens the range; the depth grows by bias * z / range = bias / |d|.
      mpi[i] = static_cast<float>(mpi_bias_m(nc_, edge_m) * inv_len);
    }
  }

  const Scene& scene_;
  const std::vector<double>& checker_per_m_;
  const CameraIntrinsics& K_;
  const NoiseConfig& nc_;
  const Eigen::Matrix3d R_;
  const Eigen::Vector3d origin_;
  const Eigen::Vector3d rx_;
  const double min_z_, max_z_;
  const bool want_mpi_;
};

// Pass 2: noise. Every random draw is a hash of (noise_key, pixel): order-independent.
class NoisePass {
 public:
  NoisePass(const RendererConfig& config, uint64_t noise_key, bool want_mpi, const float* exact,
            const float* cos_inc, const float* mpi)
      : nc_(config.noise),
        W_(config.intrinsics.width),
        H_(config.intrinsics.height),
        noise_key_(noise_key),
        want_mpi_(want_mpi),
        min_z_(config.min_depth_m),
        max_z_(config.max_depth_m),
        max_theta_(nc_.axial_max_incidence_deg * kDeg),
        grazing_start_(nc_.dropout_grazing_start_deg * kDeg),
        far_span_(std::max(1e-9, max_z_ - nc_.dropout_far_start_m)),
        exact_(exact),
        cos_inc_(cos_inc),
        mpi_(mpi) {}

  // `out` holds zeros: a pixel without a return stays 0.
  void run(float* out) const {
    for (int v = 0; v < H_; ++v) {
      for (int u = 0; u < W_; ++u) {
        const size_t i = static_cast<size_t>(v) * W_ + u;
        if (exact_[i] <= 0.0) continue;
        out[i] = noisy_depth(u, v, i);
      }
    }
  }

 private:
  // The measured depth of a pixel with an exact depth, 0 where it has no return.
  inline float noisy_depth(int u, int v, size_t i) const {
    const double z0 = exact_[i];
    const uint64_t h1 = detail::mix64(noise_key_ + 2 * i);
    const uint64_t h2 = detail::mix64(noise_key_ + 2 * i + 1);
    const double theta = fast_acos01(cos_inc_[i]);
    if (nc_.dropout_enabled && detail::uniform21(h2, 0) < dropout_probability(z0, theta))
      return 0.0f;
    if (nc_.outlier_enabled && detail::uniform21(h2, 21) < nc_.outlier_probability)
      return static_cast<float>(
          min_z_ + (max_z_ - min_z_) * detail::uniform01(detail::mix64(h1 ^ 0x5bd1e995ull)));
    double z = z0;
    if (nc_.flying_enabled && detail::uniform21(h2, 42) < nc_.flying_probability)
      z = flying_depth(u, v, z0, h2);
    if (want_mpi_) z += mpi_[i];
    if (nc_.axial_enabled)
      z += detail::fast_gaussian(h1) * nc_.axial_scale *
           fankhauser_axial_sigma_m(z0, theta, max_theta_);
    if (z < min_z_ || z > max_z_) return 0.0f;
    return static_cast<float>(z);
  }

  // A base rate, more at grazing incidence and towards the far end of the range.
  inline double dropout_probability(double z0, double theta) const {
    double p = nc_.dropout_probability;
    if (theta > grazing_start_) {
      const double g = (theta - grazing_start_) / (0.5 * kPi - grazing_start_);
      p += g * g;
    }
    if (z0 > nc_.dropout_far_start_m)
      p += nc_.dropout_far_probability * (z0 - nc_.dropout_far_start_m) / far_span_;
    return p;
  }

  // A flying pixel: where the 3x3 neighbourhood spans a depth jump, a depth drawn within it.
  inline double flying_depth(int u, int v, double z0, uint64_t h2) const {
    double lo = z0, hi = z0;
    for (int dv = -1; dv <= 1; ++dv) {
      const int vv = v + dv;
      if (vv < 0 || vv >= H_) continue;
      for (int du = -1; du <= 1; ++du) {
        const int uu = u + du;
        if (uu < 0 || uu >= W_) continue;
        const float zn = exact_[static_cast<size_t>(vv) * W_ + uu];
        if (zn <= 0.0f) continue;
        lo = std::min(lo, static_cast<double>(zn));
        hi = std::max(hi, static_cast<double>(zn));
      }
    }
    if (hi - lo > std::max(nc_.flying_min_jump_m, nc_.flying_min_jump_fraction * lo))
      return lo + (hi - lo) * detail::uniform01(detail::mix64(h2 ^ 0x27d4eb2f165667c5ull));
    return z0;
  }

  const NoiseConfig& nc_;
  const int W_, H_;
  const uint64_t noise_key_;
  const bool want_mpi_;
  const double min_z_, max_z_;
  const double max_theta_, grazing_start_, far_span_;
  const float* exact_;
  const float* cos_inc_;
  const float* mpi_;
};

// Images of the camera's size, zeroed (colour only when wanted).
void reset_images(int W, int H, DepthImage* depth, ColorImage* color) {
  const size_t n = static_cast<size_t>(W) * static_cast<size_t>(H);
  depth->width = W;
  depth->height = H;
  depth->depth_m.assign(n, 0.0f);
  if (color) {
    color->width = W;
    color->height = H;
    color->rgb.assign(3 * n, 0);
  }
}

}  // namespace

void DepthRenderer::render(const Pose& T_world_cam, uint64_t noise_key, bool with_noise,
                           DepthImage* depth, ColorImage* color) const {
  const CameraIntrinsics& K = config_.intrinsics;
  const NoiseConfig& nc = config_.noise;
  reset_images(K.width, K.height, depth, color);
  if (!scene_) return;

  const bool noisy = with_noise && nc.enabled;
  const bool want_mpi = noisy && nc.mpi_enabled && nc.mpi_max_bias_m > 0.0 && nc.mpi_range_m > 0.0;
  Scratch& scratch = thread_scratch(depth->depth_m.size());
  float* exact = noisy ? scratch.exact_m.data() : depth->depth_m.data();
  float* cos_inc = scratch.cos_incidence.data();
  float* mpi = scratch.mpi_bias_m.data();
  GeometryPass(*scene_, checker_per_m_, config_, T_world_cam, want_mpi)
      .run(&scratch, exact, cos_inc, mpi, color);
  if (!noisy) return;
  NoisePass(config_, noise_key, want_mpi, exact, cos_inc, mpi).run(depth->depth_m.data());
}

}  // namespace depthfuse::synthetic
