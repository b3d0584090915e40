// Scene geometry: validation, the acceleration grid, raycasting and distances.
#include "depthfuse/synthetic/scene.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

namespace depthfuse::synthetic {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kTMin = 1e-9;           // hits nearer than this (in ray units) are self-hits
constexpr double kSideTolerance = 1e-6;  // metres, for "in front of" / "outside of" tests
constexpr double kGridCellM = 0.5;
constexpr int kMaxGridCells = 1 << 20;
constexpr size_t kBruteForceMaxPrimitives = 8;

bool finite3(const Eigen::Vector3d& v) { return v.allFinite(); }

// Normalises v unless it already is a unit vector to the last bits (keeps TOML round trips exact).
bool normalize_in_place(Eigen::Vector3d* v) {
  const double n = v->norm();
  if (!(n > 1e-9) || !std::isfinite(n)) return false;
  if (std::fabs(n - 1.0) > 1e-12) *v /= n;
  return true;
}

std::string describe_primitive(size_t i, const Primitive& p) {
  std::string s = "primitive " + std::to_string(i) + " (" + to_string(p.kind);
  if (!p.name.empty()) s += " '" + p.name + "'";
  return s + ")";
}

// Axis-aligned bounds of a primitive; infinite for unbounded planes.
Eigen::AlignedBox3d bounds_of(const Primitive& p) {
  Eigen::AlignedBox3d box;
  if (p.kind != PrimitiveKind::kPlane) {
    box.extend(p.min_m);
    box.extend(p.max_m);
    return box;
  }
  const Eigen::Vector3d v = p.v_axis();
  for (double a : {p.u_min_m, p.u_max_m})
    for (double b : {p.v_min_m, p.v_max_m}) {
      if (!std::isfinite(a) || !std::isfinite(b)) {
        box.min().setConstant(-kInf);
        box.max().setConstant(kInf);
        return box;
      }
      box.extend(p.origin_m + a * p.u_axis + b * v);
    }
  return box;
}

}  // namespace

const char* to_string(SceneKind kind) {
  switch (kind) {
    case SceneKind::kCorner:
      return "corner";
    case SceneKind::kRoom:
      return "room";
    case SceneKind::kRooms:
      return "rooms";
    case SceneKind::kFurnished:
      return "furnished";
    case SceneKind::kPlain:
      return "plain";
  }
  return "unknown";
}

Result<SceneKind> parse_scene_kind(const std::string& text) {
  if (text == "corner") return SceneKind::kCorner;
  if (text == "room") return SceneKind::kRoom;
  if (text == "rooms") return SceneKind::kRooms;
  if (text == "furnished") return SceneKind::kFurnished;
  if (text == "plain") return SceneKind::kPlain;
  return invalid_argument("unknown synthetic scene '" + text +
                          "': expected corner, room, rooms, furnished or plain");
}

const char* to_string(PrimitiveKind kind) {
  switch (kind) {
    case PrimitiveKind::kPlane:
      return "plane";
    case PrimitiveKind::kBox:
      return "box";
    case PrimitiveKind::kRoom:
      return "room";
  }
  return "unknown";
}

Primitive Primitive::plane(const Eigen::Vector3d& origin_m, const Eigen::Vector3d& normal,
                           const Eigen::Vector3d& u_axis, double u_min_m, double u_max_m,
                           double v_min_m, double v_max_m, std::string name) {
  Primitive p;
  p.kind = PrimitiveKind::kPlane;
  p.name = std::move(name);
  p.origin_m = origin_m;
  p.normal = normal;
  p.u_axis = u_axis;
  p.u_min_m = u_min_m;
  p.u_max_m = u_max_m;
  p.v_min_m = v_min_m;
  p.v_max_m = v_max_m;
  return p;
}

Primitive Primitive::box(const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m,
                         std::string name) {
  Primitive p;
  p.kind = PrimitiveKind::kBox;
  p.name = std::move(name);
  p.min_m = min_m;
  p.max_m = max_m;
  return p;
}

Primitive Primitive::room(const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m,
                          std::string name) {
  Primitive p = box(min_m, max_m, std::move(name));
  p.kind = PrimitiveKind::kRoom;
  return p;
}

// A ray's direction and, once a box needs it, 1 / direction per axis (+-infinity where it is +-0:
// the slab test then works with IEEE infinities). Plane-only rays never divide.
struct Scene::Ray {
  explicit Ray(const Eigen::Vector3d& dir) : d{dir.x(), dir.y(), dir.z()} {}
  void need_inverse() {
    if (have_inverse) return;
    inv[0] = 1.0 / d[0];
    inv[1] = 1.0 / d[1];
    inv[2] = 1.0 / d[2];
    have_inverse = true;
  }

  double d[3];
  double inv[3] = {0.0, 0.0, 0.0};
  bool have_inverse = false;
};

Result<Scene> Scene::create(std::vector<Primitive> primitives, std::string name) {
  Scene scene;
  scene.name_ = std::move(name);
  scene.compact_.reserve(primitives.size());
  for (size_t i = 0; i < primitives.size(); ++i) {
    Primitive& p = primitives[i];
    Compact c{};
    c.kind = p.kind;
    if (!(p.checker_m >= 0.0) || !std::isfinite(p.checker_m))
      return invalid_argument(describe_primitive(i, p) + ": checker_m must be a finite length >= 0");
    if (p.kind == PrimitiveKind::kPlane) {
      if (!finite3(p.origin_m))
        return invalid_argument(describe_primitive(i, p) + ": origin_m is not finite");
      if (!finite3(p.normal) || !normalize_in_place(&p.normal))
        return invalid_argument(describe_primitive(i, p) + ": normal must be a non-zero vector");
      if (!finite3(p.u_axis) || std::fabs(p.u_axis.normalized().dot(p.normal)) > 1e-3)
        return invalid_argument(describe_primitive(i, p) +
                                ": u_axis must be a non-zero vector perpendicular to the normal");
      if (std::fabs(p.u_axis.dot(p.normal)) > 1e-12) p.u_axis -= p.u_axis.dot(p.normal) * p.normal;
      if (!normalize_in_place(&p.u_axis))
        return invalid_argument(describe_primitive(i, p) + ": u_axis must be non-zero");
      if (std::isnan(p.u_min_m) || std::isnan(p.u_max_m) || !(p.u_min_m < p.u_max_m))
        return invalid_argument(describe_primitive(i, p) +
                                ": u_range_m must be [min, max] with min < max");
      if (std::isnan(p.v_min_m) || std::isnan(p.v_max_m) || !(p.v_min_m < p.v_max_m))
        return invalid_argument(describe_primitive(i, p) +
                                ": v_range_m must be [min, max] with min < max");
      c.a = p.origin_m;
      c.b = p.normal;
      c.u = p.u_axis;
      c.v = p.v_axis();
      c.u_min = p.u_min_m;
      c.u_max = p.u_max_m;
      c.v_min = p.v_min_m;
      c.v_max = p.v_max_m;
    } else {
      if (!finite3(p.min_m) || !finite3(p.max_m))
        return invalid_argument(describe_primitive(i, p) + ": min_m and max_m must be finite");
      if (!(p.min_m.array() < p.max_m.array()).all())
        return invalid_argument(describe_primitive(i, p) +
                                ": min_m must be below max_m on every axis");
      c.a = p.min_m;
      c.b = p.max_m;
    }
    scene.compact_.push_back(c);
  }
  scene.primitives_ = std::move(primitives);
  scene.build_grid();
  return scene;
}

void Scene::build_grid() {
  bounds_.setEmpty();
  global_.clear();
  cell_begin_.clear();
  cell_items_.clear();
  nx_ = ny_ = 0;

  primitive_bounds_.clear();
  primitive_bounds_.reserve(primitives_.size());
  for (const Primitive& p : primitives_) {
    primitive_bounds_.push_back(bounds_of(p));
    const Eigen::AlignedBox3d& b = primitive_bounds_.back();
    if (b.min().allFinite() && b.max().allFinite()) bounds_.extend(b);
  }
  const std::vector<Eigen::AlignedBox3d>& boxes = primitive_bounds_;

  const bool use_grid = primitives_.size() > kBruteForceMaxPrimitives && !bounds_.isEmpty();
  if (!use_grid) {
    for (size_t i = 0; i < primitives_.size(); ++i) global_.push_back(static_cast<int>(i));
    return;
  }

  const double ex = bounds_.max().x() - bounds_.min().x();
  const double ey = bounds_.max().y() - bounds_.min().y();
  cell_m_ = kGridCellM;
  while ((std::ceil(ex / cell_m_) + 1) * (std::ceil(ey / cell_m_) + 1) > kMaxGridCells)
    cell_m_ *= 2.0;
  grid_x0_ = bounds_.min().x() - 1e-6;
  grid_y0_ = bounds_.min().y() - 1e-6;
  nx_ = std::max(1, static_cast<int>(std::ceil((ex + 2e-6) / cell_m_)));
  ny_ = std::max(1, static_cast<int>(std::ceil((ey + 2e-6) / cell_m_)));
  const long total_cells = static_cast<long>(nx_) * ny_;

  // Count, then fill (CSR).
  std::vector<int> counts(static_cast<size_t>(total_cells), 0);
  std::vector<std::array<int, 4>> ranges(primitives_.size(), {0, -1, 0, -1});
  for (size_t i = 0; i < primitives_.size(); ++i) {
    const auto& b = boxes[i];
    const bool bounded = b.min().allFinite() && b.max().allFinite();
    int ix0 = 0, ix1 = -1, iy0 = 0, iy1 = -1;
    if (bounded) {
      ix0 =
          std::clamp(static_cast<int>(std::floor((b.min().x() - grid_x0_) / cell_m_)), 0, nx_ - 1);
      ix1 =
          std::clamp(static_cast<int>(std::floor((b.max().x() - grid_x0_) / cell_m_)), 0, nx_ - 1);
      iy0 =
          std::clamp(static_cast<int>(std::floor((b.min().y() - grid_y0_) / cell_m_)), 0, ny_ - 1);
      iy1 =
          std::clamp(static_cast<int>(std::floor((b.max().y() - grid_y0_) / cell_m_)), 0, ny_ - 1);
    }
    const long covered = bounded ? static_cast<long>(ix1 - ix0 + 1) * (iy1 - iy0 + 1) : total_cells;
    if (!bounded || (covered > 16 && covered * 4 > total_cells)) {
      global_.push_back(static_cast<int>(i));
      continue;
    }
    ranges[i] = {ix0, ix1, iy0, iy1};
    for (int iy = iy0; iy <= iy1; ++iy)
      for (int ix = ix0; ix <= ix1; ++ix) ++counts[static_cast<size_t>(iy) * nx_ + ix];
  }
  cell_begin_.assign(static_cast<size_t>(total_cells) + 1, 0);
  for (long c = 0; c < total_cells; ++c) cell_begin_[c + 1] = cell_begin_[c] + counts[c];
  cell_items_.assign(static_cast<size_t>(cell_begin_.back()), -1);
  std::vector<int> fill(cell_begin_.begin(), cell_begin_.end() - 1);
  for (size_t i = 0; i < primitives_.size(); ++i) {
    const auto& r = ranges[i];
    for (int iy = r[2]; iy <= r[3]; ++iy)
      for (int ix = r[0]; ix <= r[1]; ++ix)
        cell_items_[fill[static_cast<size_t>(iy) * nx_ + ix]++] = static_cast<int>(i);
  }
}

// The terms of primitive c that depend on the ray's origin o only (prepare_view computes them
// once per view): a plane's -n.(o - a), u.(o - a), v.(o - a); a box's min - o and max - o.
__attribute__((always_inline)) inline void Scene::origin_terms(const Compact& c,
                                                               const Eigen::Vector3d& o,
                                                               double* k) {
  if (c.kind == PrimitiveKind::kPlane) {
    const Eigen::Vector3d oa = o - c.a;
    k[0] = -c.b.dot(oa);  // t = k[0] / (n . d)
    k[1] = c.u.dot(oa);   // u coordinate of the origin
    k[2] = c.v.dot(oa);   // v coordinate of the origin
    k[3] = k[4] = k[5] = 0.0;
    return;
  }
  for (int j = 0; j < 3; ++j) {
    k[j] = c.a[j] - o[j];
    k[3 + j] = c.b[j] - o[j];
  }
}

// The one ray kernel: primitive `index`, whose origin terms are k, against the ray's direction.
// A hit nearer than *best (a plane's at *best too) lowers *best and sets *face. The hit's normal
// and surface coordinates are filled once, for the nearest hit (fill_hit).
__attribute__((always_inline)) inline bool Scene::hit_nearer(int index, const double* k, Ray* ray,
                                                             double* best, int* face) const {
  const Compact& c = compact_[static_cast<size_t>(index)];
  const double d0 = ray->d[0], d1 = ray->d[1], d2 = ray->d[2];
  if (c.kind == PrimitiveKind::kPlane) {
    // t = num / denom must lie in (kTMin, best] and the hit within the rectangle; every test is
    // done scaled by |denom|, so only an accepted hit costs a division.
    double denom = c.b.x() * d0 + c.b.y() * d1 + c.b.z() * d2;
    double num = k[0];
    if (denom < 0.0) {
      denom = -denom;
      num = -num;
    } else if (!(denom > 0.0)) {
      return false;
    }
    if (!(num > kTMin * denom) || num > *best * denom) return false;
    // |denom| * (coordinate of the hit along u) = |denom| (u.(o - a)) + num (u.d), same for v.
    const double a = denom * k[1] + num * (c.u.x() * d0 + c.u.y() * d1 + c.u.z() * d2);
    if (a < c.u_min * denom || a > c.u_max * denom) return false;
    const double b = denom * k[2] + num * (c.v.x() * d0 + c.v.y() * d1 + c.v.z() * d2);
    if (b < c.v_min * denom || b > c.v_max * denom) return false;
    *best = num / denom;
    *face = 0;
    return true;
  }
  // Box surface (solid box or room): the first boundary crossing after the origin, by slabs.
  ray->need_inverse();
  const double x0 = k[0] * ray->inv[0], x1 = k[3] * ray->inv[0];
  const double y0 = k[1] * ray->inv[1], y1 = k[4] * ray->inv[1];
  const double z0 = k[2] * ray->inv[2], z1 = k[5] * ray->inv[2];
  const double nx = std::min(x0, x1), ny = std::min(y0, y1), nz = std::min(z0, z1);
  const double fx = std::max(x0, x1), fy = std::max(y0, y1), fz = std::max(z0, z1);
  const double t_near = std::max(nx, std::max(ny, nz));
  const double t_far = std::min(fx, std::min(fy, fz));
  if (!(t_near <= t_far)) return false;  // also rejects NaN from a ray in a slab's boundary plane
  int axis;
  bool max_side;  // which of the axis' two faces
  if (t_near > kTMin) {
    if (t_near >= *best) return false;
    *best = t_near;
    axis = t_near == nx ? 0 : (t_near == ny ? 1 : 2);
    max_side = ray->d[axis] < 0.0;  // entering through the max face when travelling down the axis
  } else if (t_far > kTMin && t_far < *best) {
    *best = t_far;
    axis = t_far == fx ? 0 : (t_far == fy ? 1 : 2);
    max_side = ray->d[axis] > 0.0;
  } else {
    return false;
  }
  *face = 2 * axis + (max_side ? 1 : 0);
  return true;
}

void Scene::fill_hit(int index, int face, double t, const Eigen::Vector3d& origin_w,
                     const double* k, const Eigen::Vector3d& dir_w, RayHit* hit) const {
  const Compact& c = compact_[static_cast<size_t>(index)];
  hit->t = t;
  hit->primitive = index;
  hit->face = face;
  if (c.kind == PrimitiveKind::kPlane) {
    hit->normal_w = c.b.dot(dir_w) < 0.0 ? c.b : Eigen::Vector3d(-c.b);
    hit->uv_m = Eigen::Vector2d(k[1] + t * c.u.dot(dir_w), k[2] + t * c.v.dot(dir_w));
    return;
  }
  const int axis = face / 2;
  hit->normal_w = Eigen::Vector3d::Zero();
  hit->normal_w[axis] = dir_w[axis] > 0.0 ? -1.0 : 1.0;
  const Eigen::Vector3d p = origin_w + t * dir_w;
  hit->uv_m = Eigen::Vector2d(p[(axis + 1) % 3], p[(axis + 2) % 3]);
}

bool Scene::raycast(const Eigen::Vector3d& origin_w, const Eigen::Vector3d& dir_w, double t_max,
                    RayHit* hit) const {
  Ray ray(dir_w);
  double best = t_max;
  int best_index = -1, best_face = 0;
  double k[6];
  for (int i : global_) {
    origin_terms(compact_[static_cast<size_t>(i)], origin_w, k);
    if (hit_nearer(i, k, &ray, &best, &best_face)) best_index = i;
  }
  if (nx_ != 0) traverse_grid(origin_w, &ray, &best, &best_index, &best_face);
  if (best_index < 0) return false;
  if (hit) {
    origin_terms(compact_[static_cast<size_t>(best_index)], origin_w, k);
    fill_hit(best_index, best_face, best, origin_w, k, dir_w, hit);
  }
  return true;
}

void Scene::prepare_view(const Eigen::Vector3d& origin_w, ViewCache* view) const {
  view->origin_w = origin_w;
  view->terms.resize(6 * compact_.size());
  for (size_t i = 0; i < compact_.size(); ++i) origin_terms(compact_[i], origin_w, &view->terms[6 * i]);
}

bool Scene::raycast_candidates(const ViewCache& view, const Eigen::Vector3d& dir_w,
                               const int* candidates, const double* t_lower, size_t count,
                               double t_max, RayHit* hit) const {
  Ray ray(dir_w);
  double best = t_max;
  int best_index = -1, best_face = 0;
  for (size_t n = 0; n < count; ++n) {
    if (t_lower[n] >= best) break;
    const int index = candidates[n];
    if (hit_nearer(index, &view.terms[6 * static_cast<size_t>(index)], &ray, &best, &best_face))
      best_index = index;
  }
  if (best_index < 0) return false;
  if (hit)
    fill_hit(best_index, best_face, best, view.origin_w,
             &view.terms[6 * static_cast<size_t>(best_index)], dir_w, hit);
  return true;
}

void Scene::traverse_grid(const Eigen::Vector3d& origin_w, Ray* ray, double* best_t,
                          int* best_index, int* best_face) const {
  double& best = *best_t;
  double k[6];

  // 2-D DDA over the grid (Amanatides & Woo), from where the ray enters the grid's rectangle.
  const double ox = origin_w.x(), oy = origin_w.y(), dx = ray->d[0], dy = ray->d[1];
  const double gx1 = grid_x0_ + nx_ * cell_m_, gy1 = grid_y0_ + ny_ * cell_m_;
  double t_enter = kTMin, t_exit = best;
  if (dx != 0.0) {
    double ta = (grid_x0_ - ox) / dx, tb = (gx1 - ox) / dx;
    if (ta > tb) std::swap(ta, tb);
    t_enter = std::max(t_enter, ta);
    t_exit = std::min(t_exit, tb);
  } else if (ox < grid_x0_ || ox > gx1) {
    return;
  }
  if (dy != 0.0) {
    double ta = (grid_y0_ - oy) / dy, tb = (gy1 - oy) / dy;
    if (ta > tb) std::swap(ta, tb);
    t_enter = std::max(t_enter, ta);
    t_exit = std::min(t_exit, tb);
  } else if (oy < grid_y0_ || oy > gy1) {
    return;
  }
  if (t_enter > t_exit) return;

  const double px = ox + t_enter * dx, py = oy + t_enter * dy;
  int ix = std::clamp(static_cast<int>(std::floor((px - grid_x0_) / cell_m_)), 0, nx_ - 1);
  int iy = std::clamp(static_cast<int>(std::floor((py - grid_y0_) / cell_m_)), 0, ny_ - 1);
  const int step_x = dx > 0.0 ? 1 : (dx < 0.0 ? -1 : 0);
  const int step_y = dy > 0.0 ? 1 : (dy < 0.0 ? -1 : 0);
  double t_next_x =
      step_x != 0 ? (grid_x0_ + (ix + (step_x > 0 ? 1 : 0)) * cell_m_ - ox) / dx : kInf;
  double t_next_y =
      step_y != 0 ? (grid_y0_ + (iy + (step_y > 0 ? 1 : 0)) * cell_m_ - oy) / dy : kInf;
  const double t_delta_x = step_x != 0 ? cell_m_ / std::fabs(dx) : kInf;
  const double t_delta_y = step_y != 0 ? cell_m_ / std::fabs(dy) : kInf;

  for (;;) {
    const size_t cell = static_cast<size_t>(iy) * nx_ + ix;
    for (int j = cell_begin_[cell], end = cell_begin_[cell + 1]; j < end; ++j) {
      const int i = cell_items_[j];
      origin_terms(compact_[static_cast<size_t>(i)], origin_w, k);
      if (hit_nearer(i, k, ray, &best, best_face)) *best_index = i;
    }
    const double cell_exit = std::min(t_next_x, t_next_y);
    if (cell_exit >= best || cell_exit >= t_exit) break;
    if (t_next_x < t_next_y) {
      ix += step_x;
      if (ix < 0 || ix >= nx_) break;
      t_next_x += t_delta_x;
    } else {
      iy += step_y;
      if (iy < 0 || iy >= ny_) break;
      t_next_y += t_delta_y;
    }
  }
}

bool Scene::raycast(const Eigen::Vector3d& origin_w, const Eigen::Vector3d& dir_w, double* t_m,
                    Eigen::Vector3d* normal_w) const {
  RayHit hit;
  if (!raycast(origin_w, dir_w, kInf, &hit)) return false;
  if (t_m) *t_m = hit.t;
  if (normal_w) *normal_w = hit.normal_w;
  return true;
}

// Distance from p to a primitive's surface and the nearest point q there, unless it is certainly
// not below `bound` (then returns bound or more without q). `outside` tells for boxes and rooms
// whether p is outside the box.
__attribute__((always_inline)) inline double Scene::surface_distance(
    const Compact& c, const Eigen::Vector3d& p, double bound, Eigen::Vector3d* q, bool* outside) {
  if (c.kind == PrimitiveKind::kPlane) {
    const Eigen::Vector3d w = p - c.a;
    const double h = c.b.dot(w);
    if (std::fabs(h) >= bound) return std::fabs(h);  // the plane's distance is a lower bound
    const double s = std::clamp(c.u.dot(w), c.u_min, c.u_max);
    const double t = std::clamp(c.v.dot(w), c.v_min, c.v_max);
    *q = c.a + s * c.u + t * c.v;
    *outside = true;
    return (p - *q).norm();
  }
  const Eigen::Vector3d clamped = p.cwiseMax(c.a).cwiseMin(c.b);
  if (clamped != p) {
    const double d2 = (p - clamped).squaredNorm();
    if (d2 >= bound * bound) return bound;
    *q = clamped;
    *outside = true;
    return std::sqrt(d2);
  }
  *outside = false;
  double best = std::numeric_limits<double>::infinity();
  *q = p;
  for (int k = 0; k < 3; ++k) {
    const double lo = p[k] - c.a[k], hi = c.b[k] - p[k];
    if (lo < best) {
      best = lo;
      *q = p;
      (*q)[k] = c.a[k];
    }
    if (hi < best) {
      best = hi;
      *q = p;
      (*q)[k] = c.b[k];
    }
  }
  return best;
}

template <typename Fn>
void Scene::for_cells_in_xy_box(double x0, double y0, double x1, double y1, Fn&& fn) const {
  if (nx_ == 0) return;
  const int ix0 = std::clamp(static_cast<int>(std::floor((x0 - grid_x0_) / cell_m_)), 0, nx_ - 1);
  const int ix1 = std::clamp(static_cast<int>(std::floor((x1 - grid_x0_) / cell_m_)), 0, nx_ - 1);
  const int iy0 = std::clamp(static_cast<int>(std::floor((y0 - grid_y0_) / cell_m_)), 0, ny_ - 1);
  const int iy1 = std::clamp(static_cast<int>(std::floor((y1 - grid_y0_) / cell_m_)), 0, ny_ - 1);
  for (int iy = iy0; iy <= iy1; ++iy)
    for (int ix = ix0; ix <= ix1; ++ix) fn(static_cast<size_t>(iy) * nx_ + ix);
}

double Scene::distance_m(const Eigen::Vector3d& p_w) const {
  double best = kInf;
  Eigen::Vector3d q;
  bool outside;
  auto visit = [&](int i) {
    best =
        std::min(best, surface_distance(compact_[static_cast<size_t>(i)], p_w, best, &q, &outside));
  };
  for (int i : global_) visit(i);
  if (nx_ == 0) return best;

  // Rings of cells around p's (clamped) cell: a cell k rings away is at least (k - 1) cells away
  // in x-y, so once that exceeds the best distance nothing farther can be nearer.
  const int cx =
      std::clamp(static_cast<int>(std::floor((p_w.x() - grid_x0_) / cell_m_)), 0, nx_ - 1);
  const int cy =
      std::clamp(static_cast<int>(std::floor((p_w.y() - grid_y0_) / cell_m_)), 0, ny_ - 1);
  const int max_ring = std::max(nx_, ny_);
  for (int k = 0; k <= max_ring; ++k) {
    if ((k - 1) * cell_m_ > best) break;
    for (int iy = cy - k; iy <= cy + k; ++iy) {
      if (iy < 0 || iy >= ny_) continue;
      const bool edge_row = iy == cy - k || iy == cy + k;
      for (int ix = cx - k; ix <= cx + k; ix += (edge_row || k == 0) ? 1 : 2 * k) {
        if (ix < 0 || ix >= nx_) continue;
        const size_t cell = static_cast<size_t>(iy) * nx_ + ix;
        for (int j = cell_begin_[cell]; j < cell_begin_[cell + 1]; ++j) visit(cell_items_[j]);
      }
    }
  }
  return best;
}

// Distance to the room's two neighbouring walls when p lies on a face of a room (every edge of a
// room is concave); max_distance_m otherwise.
inline double Scene::own_concave_distance(const Eigen::Vector3d& p_w, int primitive, int face,
                                          double max_distance_m) const {
  double best = max_distance_m;
  if (primitive < 0 || static_cast<size_t>(primitive) >= compact_.size()) return best;
  const Compact& c = compact_[static_cast<size_t>(primitive)];
  if (c.kind != PrimitiveKind::kRoom) return best;
  const int axis = face / 2;
  for (int k = 0; k < 3; ++k) {
    if (k == axis) continue;
    best = std::min(best, std::min(p_w[k] - c.a[k], c.b[k] - p_w[k]));
  }
  return best;
}

// Lowers *best to the distance from p to primitive i when i forms a concave edge with the surface
// at p (normal_w facing the viewer).
__attribute__((always_inline)) inline void Scene::concave_visit(int i, const Eigen::Vector3d& p_w,
                                                                const Eigen::Vector3d& normal_w,
                                                                int primitive, double* best) const {
  if (i == primitive) return;
  const Compact& c = compact_[static_cast<size_t>(i)];
  Eigen::Vector3d q;
  bool outside;
  const double d = surface_distance(c, p_w, *best, &q, &outside);
  if (!(d < *best)) return;
  if ((q - p_w).dot(normal_w) < -kSideTolerance) return;  // behind the surface at p: convex
  switch (c.kind) {
    case PrimitiveKind::kPlane:
      if ((p_w - q).dot(c.b) < -kSideTolerance) return;  // p on the plane's back side
      break;
    case PrimitiveKind::kBox:
      if (!outside) return;
      break;
    case PrimitiveKind::kRoom:
      if (outside) return;
      break;
  }
  *best = d;
}

double Scene::concave_edge_distance_m(const Eigen::Vector3d& p_w, const Eigen::Vector3d& normal_w,
                                      int primitive, int face, double max_distance_m) const {
  double best = own_concave_distance(p_w, primitive, face, max_distance_m);
  for (int i : global_) concave_visit(i, p_w, normal_w, primitive, &best);
  for_cells_in_xy_box(p_w.x() - best, p_w.y() - best, p_w.x() + best, p_w.y() + best,
                      [&](size_t cell) {
                        for (int j = cell_begin_[cell]; j < cell_begin_[cell + 1]; ++j)
                          concave_visit(cell_items_[j], p_w, normal_w, primitive, &best);
                      });
  return best;
}

double Scene::concave_edge_distance_m(const Eigen::Vector3d& p_w, const Eigen::Vector3d& normal_w,
                                      int primitive, int face, double max_distance_m,
                                      const int* candidates, size_t count) const {
  double best = own_concave_distance(p_w, primitive, face, max_distance_m);
  for (size_t k = 0; k < count; ++k) concave_visit(candidates[k], p_w, normal_w, primitive, &best);
  return best;
}

}  // namespace depthfuse::synthetic
