#include "depthfuse/fusion.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "geometry.hpp"
#include "model_projection.hpp"
#include "parallel.hpp"

namespace depthfuse {

bool merge_measurement(const Eigen::Vector3f& p_e, const Eigen::Matrix3f& L_e,
                       const Eigen::Vector3f& p_n, const Eigen::Matrix3f& L_n,
                       Eigen::Vector3f* p_fused, Eigen::Matrix3f* L_fused) {
  Eigen::Vector3f p;
  Sym3f L;
  if (!merge_rule(p_e, Sym3f::from(L_e), p_n, Sym3f::from(L_n), &p, &L)) return false;
  *p_fused = p;
  *L_fused = L.matrix();
  return true;
}

namespace {

// One image row's measurements, worked out for the whole row at once (a loop without branches that
// the compiler vectorises): world position and normal, range, information, and the merge with the
// candidate rendered at the measurement's own pixel.
struct RowScratch {
  std::vector<float> p_x, p_y, p_z, n_x, n_y, n_z, range;
  std::vector<float> l_xx, l_xy, l_xz, l_yy, l_yz, l_zz;  // the measurement's information
  std::vector<float> f_x, f_y, f_z;                       // the point merged with the candidate
  std::vector<float> fn_x, fn_y, fn_z;                    // ... and its normal
  std::vector<uint8_t> merges;                            // ... if the merge rule accepts it
  // With the usual 3x3 window: the candidate in the pixel's window, its own excluded, nearest in
  // the measurement's metric, as the candidates stood before the row was fused
  // (FrameFusion::select_window()): its pixel, -1 if none.
  std::vector<int32_t> window_px;

  // Measurement u of the row: world position, normal and information.
  Eigen::Vector3f position(int u) const { return {p_x[u], p_y[u], p_z[u]}; }
  Eigen::Vector3f normal(int u) const { return {n_x[u], n_y[u], n_z[u]}; }
  Sym3f information(int u) const {
    return {l_xx[u], l_xy[u], l_xz[u], l_yy[u], l_yz[u], l_zz[u]};
  }

  void resize(int width) {
    const size_t n = static_cast<size_t>(std::max(0, width));
    for (auto* v : {&p_x, &p_y, &p_z, &n_x, &n_y, &n_z, &range, &l_xx, &l_xy, &l_xz, &l_yy, &l_yz,
                    &l_zz, &f_x, &f_y, &f_z, &fn_x, &fn_y, &fn_z})
      v->resize(n);
    merges.resize(n);
    window_px.resize(n);
  }
};

}  // namespace

struct Fuser::Scratch {
  PointArrays added[3];  // new points of the bands: top, bottom, and the seam between them
  RowScratch rows[2];    // one per thread
};

Fuser::Fuser(const SensorModelConfig& sensor, const FusionConfig& fusion)
    : sensor_config_(sensor),
      config_(fusion),
      projection_(std::make_unique<ModelProjection>()),
      scratch_(std::make_unique<Scratch>()) {}

Fuser::~Fuser() = default;

namespace {

// Calls visit(pixel) for each pixel of the (2r + 1)^2 window around (u, v) that lies in the image,
// row by row, the centre included, until visit returns true. Returns whether it did.
template <typename Visit>
inline bool any_in_window(int u, int v, int r, int width, int height, Visit&& visit) {
  for (int vv = std::max(0, v - r); vv <= std::min(height - 1, v + r); ++vv) {
    for (int uu = std::max(0, u - r); uu <= std::min(width - 1, u + r); ++uu) {
      if (visit(static_cast<size_t>(vv) * width + uu)) return true;
    }
  }
  return false;
}

void add_stats(const FusionStats& s, FusionStats* total) {
  total->measurements += s.measurements;
  total->merged += s.merged;
  total->added += s.added;
  total->violations += s.violations;
  total->redundant += s.redundant;
}

inline uint16_t saturating_increment(uint16_t v) {
  return v == std::numeric_limits<uint16_t>::max() ? v : static_cast<uint16_t>(v + 1);
}

inline void set_information(PointState* s, const Sym3f& L) {
  s->info_xx = L.xx; s->info_xy = L.xy; s->info_xz = L.xz;
  s->info_yy = L.yy; s->info_yz = L.yz; s->info_zz = L.zz;
}

// Refines existing point i of `a` with a measurement: the merge rule's position p and information
// L, and n, the running mean of the normals (running_mean_normal()).
inline void refine_point(PointArrays& a, size_t i, const Eigen::Vector3f& p, const Sym3f& L,
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

// Merges the candidate rendered at `px` into (p_f, L_f), the merge rule's result, with normal n_f;
// `row` is the image row being fused.
inline void merge_into_candidate(ModelProjection& proj, size_t px, const Eigen::Vector3f& p_f,
                                 const Sym3f& L_f, const Eigen::Vector3f& n_f, const uint8_t* rgb,
                                 uint32_t frame_id, int row) {
  PointArrays& a = proj.candidate_points(px);
  const size_t j = proj.candidate_index(px);
  refine_point(a, j, p_f, L_f, n_f, rgb, frame_id);
  proj.record_merge(px, p_f, L_f, n_f, a.state[j].merges, row);
}

// Merges the measurement into the candidate rendered at `px` if the merge rule allows it.
inline bool try_merge(ModelProjection& proj, size_t px, const Eigen::Vector3f& p_w, const Sym3f& L_n,
                      const Eigen::Vector3f& n_w, const uint8_t* rgb, uint32_t frame_id, int row) {
  Eigen::Vector3f p_f;
  Sym3f L_f;
  if (!merge_rule(proj.candidate_position(px), proj.candidate_information(px), p_w, L_n, &p_f,
                  &L_f))
    return false;
  const Eigen::Vector3f n_f = running_mean_normal(static_cast<float>(proj.candidate_merges(px)),
                                                  proj.candidate_normal(px), n_w);
  merge_into_candidate(proj, px, p_f, L_f, n_f, rgb, frame_id, row);
  return true;
}

// One frame's fusion over a band of image rows. Bands that are two rows apart touch disjoint
// pixels and points (a point is rendered at exactly one pixel, and the candidate window reaches
// one row), so two of them can run at once; points a band adds go to its own list and reach the
// map afterwards.
class FrameFusion {
 public:
  FrameFusion(const MeasurementImage& m, const ColorImage* color, const Pose& T_world_cam,
              uint32_t frame_id, const SensorModel& model, const FusionConfig& config,
              ModelProjection* proj)
      : m_(m),
        color_(color && !color->empty() && color->width == m.width && color->height == m.height
                   ? color
                   : nullptr),
        frame_id_(frame_id),
        model_(model),
        proj_(*proj),
        R_(T_world_cam.linear().cast<float>()),
        t_(T_world_cam.translation().cast<float>()),
        up_w_(R_.col(1)),
        cr_(std::max(0, config.candidate_radius_px)),
        range_fraction_(static_cast<float>(config.visibility_range_fraction)),
        redundancy_gate2_(static_cast<float>(config.redundancy_gate * config.redundancy_gate)),
        redundancy_min_merges_(std::max(0, config.redundancy_min_merges)) {}

  // Fuses rows [v0, v1); new points are appended to *added. Gathers the candidates of rows
  // [g0, g1) (see ModelProjection::gather_candidates()), each before the first row whose candidate
  // window reaches it: the rows a band gathers are the rows it alone touches.
  void rows(int v0, int v1, int g0, int g1, RowScratch* row, PointArrays* added,
            FusionStats* total) const;

 private:
  // The first pass over row v: RowScratch for every pixel, valid or not.
  DF_VECTOR_CLONES void prepare_row(int v, RowScratch* row) const;
  // The second with a 3x3 window, after prepare_row(): RowScratch::window_px for every pixel of
  // row v. (With other windows the row loop searches where it needs to.)
  void select_window(int v, RowScratch* row) const;
  DF_VECTOR_CLONES void select_window_3x3(int v, RowScratch* row) const;  // 3x3, inner pixels
  // The candidate in the window around pixel (u, v), its own excluded, nearest to the measurement
  // (p_w, L_n) in the measurement's metric, as the candidates stand now: its pixel, -1 if none.
  int32_t nearest_in_window(int u, int v, const Eigen::Vector3f& p_w, const Sym3f& L_n) const;
  const MeasurementImage& m_;
  const ColorImage* color_;
  uint32_t frame_id_;
  const SensorModel& model_;
  ModelProjection& proj_;
  Eigen::Matrix3f R_;
  Eigen::Vector3f t_, up_w_;
  // Whether an existing point in the (2 cr + 1)^2 window around pixel (u, v) lies within the
  // redundancy gate of the measurement (p_w, L_n).
  bool explained(int u, int v, const Eigen::Vector3f& p_w, const Sym3f& L_n) const;

  int cr_;
  float range_fraction_;
  float redundancy_gate2_;  // squared Mahalanobis distance; 0: off
  int redundancy_min_merges_;
};

bool FrameFusion::explained(int u, int v, const Eigen::Vector3f& p_w, const Sym3f& L_n) const {
  // The merge count as it is now: a merge earlier in this frame counts.
  const ModelProjection& proj = proj_;
  return any_in_window(u, v, cr_, m_.width, m_.height, [&](size_t px) {
    return proj.has_candidate(px) && proj.candidate_merges(px) >= redundancy_min_merges_ &&
           mahalanobis2(Eigen::Vector3f(proj.candidate_position(px) - p_w), L_n) <=
               redundancy_gate2_;
  });
}

void FrameFusion::prepare_row(int v, RowScratch* row) const {
  // Plain pointers for the loop; `ivdep` tells the compiler what it cannot prove (GCC ignores
  // restrict on locals): no store here reaches another iteration's inputs, so it may vectorise.
  const int W = m_.width;
  const size_t i0 = static_cast<size_t>(v) * W;
  const float* X = m_.x.data() + i0;
  const float* Y = m_.y.data() + i0;
  const float* Z = m_.z.data() + i0;
  const float* NX = m_.nx.data() + i0;
  const float* NY = m_.ny.data() + i0;
  const float* NZ = m_.nz.data() + i0;
  const ModelProjection::CandidateColumns c = proj_.candidate_columns(i0);
  const float* CX = c.x;
  const float* CY = c.y;
  const float* CZ = c.z;
  const float* CXX = c.xx;
  const float* CXY = c.xy;
  const float* CXZ = c.xz;
  const float* CYY = c.yy;
  const float* CYZ = c.yz;
  const float* CZZ = c.zz;
  const float* CNX = c.nx;
  const float* CNY = c.ny;
  const float* CNZ = c.nz;
  const uint16_t* CM = c.merges;
  float* p_x = row->p_x.data();
  float* p_y = row->p_y.data();
  float* p_z = row->p_z.data();
  float* n_x = row->n_x.data();
  float* n_y = row->n_y.data();
  float* n_z = row->n_z.data();
  float* range_m = row->range.data();
  float* l_xx = row->l_xx.data();
  float* l_xy = row->l_xy.data();
  float* l_xz = row->l_xz.data();
  float* l_yy = row->l_yy.data();
  float* l_yz = row->l_yz.data();
  float* l_zz = row->l_zz.data();
  float* f_x = row->f_x.data();
  float* f_y = row->f_y.data();
  float* f_z = row->f_z.data();
  float* fn_x = row->fn_x.data();
  float* fn_y = row->fn_y.data();
  float* fn_z = row->fn_z.data();
  uint8_t* merges = row->merges.data();
  const Eigen::Matrix3f R = R_;
  const Eigen::Vector3f t = t_, up = up_w_;
  const SensorModel& model = model_;
  DF_IVDEP
  for (int u = 0; u < W; ++u) {
    const Eigen::Vector3f p_c(X[u], Y[u], Z[u]);
    const Eigen::Vector3f ray_w = rotate(R, p_c);
    const Eigen::Vector3f p_w = ray_w + t;
    const Eigen::Vector3f n_w = rotate(R, Eigen::Vector3f(NX[u], NY[u], NZ[u]));
    const float range = std::sqrt(p_c.squaredNorm());  // norm() would not vectorise
    float w_x, w_y, w_z;
    model.information_weights(Z[u], &w_x, &w_y, &w_z);
    const Sym3f L_n = ray_information(ray_w * (1.0f / range), up, w_x, w_y, w_z);
    Eigen::Vector3f p_f;
    Sym3f L_f;
    const Sym3f L_e{CXX[u], CXY[u], CXZ[u], CYY[u], CYZ[u], CZZ[u]};
    merges[u] = merge_rule(Eigen::Vector3f(CX[u], CY[u], CZ[u]), L_e, p_w, L_n, &p_f, &L_f);
    p_x[u] = p_w.x(); p_y[u] = p_w.y(); p_z[u] = p_w.z();
    n_x[u] = n_w.x(); n_y[u] = n_w.y(); n_z[u] = n_w.z();
    range_m[u] = range;
    l_xx[u] = L_n.xx; l_xy[u] = L_n.xy; l_xz[u] = L_n.xz;
    l_yy[u] = L_n.yy; l_yz[u] = L_n.yz; l_zz[u] = L_n.zz;
    f_x[u] = p_f.x(); f_y[u] = p_f.y(); f_z[u] = p_f.z();
    const Eigen::Vector3f n_f =
        running_mean_normal(static_cast<float>(CM[u]), Eigen::Vector3f(CNX[u], CNY[u], CNZ[u]), n_w);
    fn_x[u] = n_f.x(); fn_y[u] = n_f.y(); fn_z[u] = n_f.z();
  }
}

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

int32_t FrameFusion::nearest_in_window(int u, int v, const Eigen::Vector3f& p_w,
                                       const Sym3f& L_n) const {
  const size_t i = static_cast<size_t>(v) * m_.width + u;
  float best_d2 = std::numeric_limits<float>::infinity();
  int32_t best_px = -1;
  any_in_window(u, v, cr_, m_.width, m_.height, [&](size_t px) {
    consider_candidate(px != i && proj_.has_candidate(px), static_cast<int32_t>(px),
                       proj_.candidate_position(px), p_w, L_n, &best_d2, &best_px);
    return false;
  });
  return best_px;
}

void FrameFusion::select_window(int v, RowScratch* row) const {
  const int W = m_.width;
  auto at = [&](int u) {
    row->window_px[u] = nearest_in_window(u, v, row->position(u), row->information(u));
  };
  if (v == 0 || v == m_.height - 1 || W < 3) {
    for (int u = 0; u < W; ++u) at(u);
    return;
  }
  select_window_3x3(v, row);
  at(0);
  at(W - 1);
}

void FrameFusion::select_window_3x3(int v, RowScratch* row) const {
  // The usual window, away from the image's border: one vectorised pass, the eight neighbours
  // written out in the window's row-major order, like nearest_in_window(). (It calls nothing: with
  // a call out of its AVX2 clone GCC left out the vzeroupper, and the scalar code after it ran
  // 15 % slower.)
  const int W = m_.width;
  const float* p_x = row->p_x.data();
  const float* p_y = row->p_y.data();
  const float* p_z = row->p_z.data();
  const float* l_xx = row->l_xx.data();
  const float* l_xy = row->l_xy.data();
  const float* l_xz = row->l_xz.data();
  const float* l_yy = row->l_yy.data();
  const float* l_yz = row->l_yz.data();
  const float* l_zz = row->l_zz.data();
  int32_t* window_px = row->window_px.data();
  const size_t i0 = static_cast<size_t>(v) * W;
  const ModelProjection::CandidateColumns above = proj_.candidate_columns(i0 - W);
  const ModelProjection::CandidateColumns same = proj_.candidate_columns(i0);
  const ModelProjection::CandidateColumns below = proj_.candidate_columns(i0 + W);
  const float *ax = above.x, *ay = above.y, *az = above.z;
  const float *sx = same.x, *sy = same.y, *sz = same.z;
  const float *bx = below.x, *by = below.y, *bz = below.z;
  const int32_t *as = above.slot, *ss = same.slot, *bs = below.slot;
  const int32_t pa = static_cast<int32_t>(i0 - W), ps = static_cast<int32_t>(i0),
                pb = static_cast<int32_t>(i0 + W);
  DF_IVDEP
  for (int u = 1; u < W - 1; ++u) {
    const Eigen::Vector3f p_w(p_x[u], p_y[u], p_z[u]);
    const Sym3f L_n{l_xx[u], l_xy[u], l_xz[u], l_yy[u], l_yz[u], l_zz[u]};
    float d2 = std::numeric_limits<float>::infinity();
    int32_t px = -1;
    auto at = [&](const float* x, const float* y, const float* z, int n) {
      return Eigen::Vector3f(x[n], y[n], z[n]);
    };
    consider_candidate(as[u - 1] >= 0, pa + u - 1, at(ax, ay, az, u - 1), p_w, L_n, &d2, &px);
    consider_candidate(as[u] >= 0, pa + u, at(ax, ay, az, u), p_w, L_n, &d2, &px);
    consider_candidate(as[u + 1] >= 0, pa + u + 1, at(ax, ay, az, u + 1), p_w, L_n, &d2, &px);
    consider_candidate(ss[u - 1] >= 0, ps + u - 1, at(sx, sy, sz, u - 1), p_w, L_n, &d2, &px);
    consider_candidate(ss[u + 1] >= 0, ps + u + 1, at(sx, sy, sz, u + 1), p_w, L_n, &d2, &px);
    consider_candidate(bs[u - 1] >= 0, pb + u - 1, at(bx, by, bz, u - 1), p_w, L_n, &d2, &px);
    consider_candidate(bs[u] >= 0, pb + u, at(bx, by, bz, u), p_w, L_n, &d2, &px);
    consider_candidate(bs[u + 1] >= 0, pb + u + 1, at(bx, by, bz, u + 1), p_w, L_n, &d2, &px);
    window_px[u] = px;
  }
}

void FrameFusion::rows(int v0, int v1, int g0, int g1, RowScratch* row, PointArrays* added,
                       FusionStats* total) const {
  // Counted here, added to *total at the end: the loop's byte stores (flags, colours) may alias
  // *total, which would cost a load and a store per count.
  FusionStats counts;
  const MeasurementImage& m = m_;
  ModelProjection& proj = proj_;
  const Eigen::Vector3f& t = t_;
  const int cr = cr_;
  const size_t W = static_cast<size_t>(m.width);
  const RowScratch& r = *row;
  int gathered = g0;  // rows [g0, gathered) are gathered
  for (int v = v0; v < v1; ++v) {
    const int g = std::min(g1, v + cr + 1);
    if (gathered < g) {
      proj.gather_candidates(gathered * W, g * W);
      gathered = g;
    }
    prepare_row(v, row);
    if (cr == 1) select_window(v, row);
    for (int u = 0; u < m.width; ++u) {
      const size_t i = static_cast<size_t>(v) * m.width + u;
      if (!m.valid[i]) continue;
      ++counts.measurements;
      const Eigen::Vector3f p_w = r.position(u);
      const Eigen::Vector3f n_w = r.normal(u);
      const Sym3f L_n = r.information(u);
      const float z = m.z[i];
      const float range = r.range[u];
      const uint8_t* rgb = color_ ? &color_->rgb[3 * i] : nullptr;

      // The candidate at this very pixel (ModelProjection::render()) first; only if it is missing
      // or does not merge, the other candidate in the window nearest in the measurement's own
      // metric (its information L_n, which weighs depth less than the lateral offset: by plain
      // distance the neighbour whose error matches the measurement's noise would win).
      // Searching the window first would merge the measurement with its neighbour's point and
      // leave its own pixel's point unrefined. The merge with the pixel's own candidate as its
      // columns stood before this row was fused was worked out in prepare_row(); if a measurement
      // of this row has refined that candidate since, the merge is worked out again. A 3x3
      // window's candidate was chosen on the candidates as they stood before this row too
      // (select_window()); if it does not merge, the one nearest as they stand now gets a try,
      // for this row's merges may have moved it. (Without that second try a sparse cloud seen
      // from nearer grows layers: Fuser.NearViewsRefineASparseCloudWithoutSpreadingIt, 14 k
      // points instead of 9 k.) Other windows are searched as they stand now.
      bool merged = false;
      if (proj.has_candidate(i) && proj.merged_in_row(i) == v) {
        merged = try_merge(proj, i, p_w, L_n, n_w, rgb, frame_id_, v);
      } else if (proj.has_candidate(i) && r.merges[u]) {
        merge_into_candidate(proj, i, Eigen::Vector3f(r.f_x[u], r.f_y[u], r.f_z[u]),
                             proj.candidate_information(i) + L_n,
                             Eigen::Vector3f(r.fn_x[u], r.fn_y[u], r.fn_z[u]), rgb, frame_id_, v);
        merged = true;
      }
      if (!merged && cr > 0) {
        const int32_t chosen = cr == 1 ? r.window_px[u] : nearest_in_window(u, v, p_w, L_n);
        if (chosen >= 0) merged = try_merge(proj, chosen, p_w, L_n, n_w, rgb, frame_id_, v);
        if (!merged && chosen >= 0 && cr == 1) {
          const int32_t now = nearest_in_window(u, v, p_w, L_n);
          if (now >= 0 && now != chosen)
            merged = try_merge(proj, now, p_w, L_n, n_w, rgb, frame_id_, v);
        }
      }
      if (merged) {
        ++counts.merged;
        continue;
      }

      // Not merged. The front-most point at this pixel in front of the measurement, both facing
      // the camera, and within a tenth of the range: the camera saw through it (paper eq. 2-3).
      if (!proj.empty_at(i)) {
        const float z_e = proj.depth_at(i);
        if (z_e < z) {
          uint32_t j;
          PointArrays& a = proj.front_points(i, &j);
          const Eigen::Vector3f& p_e = a.position(j);
          const float s_e = (p_e - t).norm();
          const bool facing_e = a.normal(j).dot(t - p_e) > 0.0f;
          const bool facing_n = n_w.dot(t - p_w) > 0.0f;
          if (facing_e && facing_n && std::abs(s_e - range) < range_fraction_ * range) {
            a.state[j].violations = saturating_increment(a.state[j].violations);
            ++counts.violations;
          }
        }
      }

      // Not merged, but an existing point is within the measurement's own (scaled) ellipsoid: the
      // surface there is already in the map, and a new point would only add a layer.
      if (redundancy_gate2_ > 0.0f && explained(u, v, p_w, L_n)) {
        ++counts.redundant;
        continue;
      }

      PointState st{};
      set_information(&st, L_n);
      st.nx = n_w.x();
      st.ny = n_w.y();
      st.nz = n_w.z();
      if (rgb) { st.r = rgb[0]; st.g = rgb[1]; st.b = rgb[2]; }
      st.last_frame = frame_id_;
      added->push_back(p_w, st);
      ++counts.added;
    }
  }
  add_stats(counts, total);
}

// Appends a band's new points to their chunks, in order.
void add_points(const PointArrays& added, uint32_t frame_id, PointMap* map) {
  // Chunk lookups repeat for neighbouring points: remember the last one.
  ChunkKey last_key{std::numeric_limits<int32_t>::min(), 0, 0};
  Chunk* last_chunk = nullptr;
  for (size_t i = 0; i < added.size(); ++i) {
    const ChunkKey key = map->key_for(added.position_m[i]);
    if (!last_chunk || key != last_key) {
      last_chunk = &map->get_or_create(key);
      last_chunk->last_touched_frame = frame_id;
      last_chunk->dirty = true;
      last_key = key;
    }
    last_chunk->points.push_back(added.position_m[i], added.state[i]);
  }
}

}  // namespace

FusionStats Fuser::fuse(const MeasurementImage& m, const ColorImage* color, const Pose& T_world_cam,
                        uint32_t frame_id, PointMap* map) {
  const SensorModel model(sensor_config_, m.intrinsics);

  // Existing points near this frame's measurements, rendered into its camera.
  ModelProjection& proj = *projection_;
  proj.set_threads(config_.threads);
  proj.select_chunks(*map, m, T_world_cam, 0.1f);
  proj.render(T_world_cam, m, model);

  const FrameFusion frame(m, color, T_world_cam, frame_id, model, config_, &proj);
  FusionStats stats[3];
  PointArrays* added = scratch_->added;
  for (PointArrays& a : scratch_->added) a.clear();
  RowScratch* row = scratch_->rows;
  for (RowScratch& r : scratch_->rows) r.resize(m.width);
  // Bands: rows [0, h - r) and [h + r, height), on two threads if there are two, then the seam
  // [h - r, h + r) once both are done (r: at least the candidate window's reach cr). With one
  // thread the bands run in the same order, so the result does not depend on the thread count.
  // Each band gathers the candidates of the rows its windows reach; the seam, those left.
  const int cr = std::max(0, config_.candidate_radius_px);
  const int r = std::max(1, cr);
  const int h = m.height / 2;
  const int H = m.height;
  if (H > 8 * r) {
    run_pair(
        config_.threads,
        [&] { frame.rows(0, h - r, 0, h - r + cr, &row[0], &added[0], &stats[0]); },
        [&] { frame.rows(h + r, H, h + r - cr, H, &row[1], &added[1], &stats[1]); });
    frame.rows(h - r, h + r, h - r + cr, h + r - cr, &row[0], &added[2], &stats[2]);
  } else {
    frame.rows(0, H, 0, H, &row[0], &added[0], &stats[0]);
  }
  FusionStats total;
  for (int b = 0; b < 3; ++b) {
    add_points(added[b], frame_id, map);
    add_stats(stats[b], &total);
  }

  // The chunks this frame observed: eviction keeps recently seen chunks, checkpoints write
  // changed ones.
  for (Chunk* c : proj.chunks()) {
    c->last_touched_frame = frame_id;
    c->dirty = true;
  }
  return total;
}

size_t postfilter(PointMap* map) {
  size_t removed = 0;
  std::vector<uint8_t> keep;
  map->for_each_chunk([&](const ChunkKey&, Chunk& c) {
    PointArrays& a = c.points;
    keep.resize(a.size());
    bool any = false;
    for (size_t i = 0; i < a.size(); ++i) {
      keep[i] = a.state[i].violations <= a.state[i].merges;
      any |= !keep[i];
    }
    if (any) {
      removed += a.compact(keep);
      c.dirty = true;
    }
  });
  return removed;
}

}  // namespace depthfuse
