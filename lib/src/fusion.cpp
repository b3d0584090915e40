#include "depthfuse/fusion.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <unordered_map>
#include <vector>

#include "fusion_columns.hpp"
#include "fusion_kernels.hpp"
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

// Neighbouring new points share a chunk: points [begin, end) of band `band` lie in chunk `key`.
struct PointRun {
  ChunkKey key;
  int band;
  size_t begin, end;
};

struct Fuser::Scratch {
  PointArrays added[3];  // new points of the bands: top, bottom, and the seam between them
  RowScratch rows[2];    // one per thread
  // The bands' new points as runs of neighbours in one chunk, and the points each chunk takes
  // (add_points()).
  std::vector<PointRun> runs;
  std::unordered_map<ChunkKey, size_t, ChunkKeyHash> added_per_chunk;
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
        camera_{T_world_cam.linear().cast<float>(), T_world_cam.translation().cast<float>(),
                T_world_cam.linear().cast<float>().col(1)},
        cr_(std::max(0, config.candidate_radius_px)),
        range_fraction_(static_cast<float>(config.visibility_range_fraction)),
        redundancy_gate2_(static_cast<float>(config.redundancy_gate * config.redundancy_gate)),
        redundancy_min_merges_(std::max(0, config.redundancy_min_merges)) {}

  // Fuses rows [v0, v1); new points are appended to *added. Gathers the candidates of rows
  // [g0, g1) (see ModelProjection::gather_candidates()), each before the first row whose candidate
  // window reaches it: the rows a band gathers are the rows it alone touches.
  void rows(int v0, int v1, int g0, int g1, RowScratch* scratch, PointArrays* added,
            FusionStats* total) const;

 private:
  // A valid measurement at pixel (u, v), as prepare_row() worked it out.
  struct Measurement {
    int u, v;
    size_t pixel;
    Eigen::Vector3f p_w, n_w;  // world frame
    Sym3f L;                   // information, 1/m^2
    float z_m, range_m;        // depth, and distance from the camera
    const uint8_t* rgb;        // null without colour
  };
  DF_INLINE Measurement measurement(const RowColumns& row, int u, int v) const;

  // The row's passes before the loop over its pixels (fusion_kernels.hpp): prepare_row(), and
  // with the usual 3x3 window the window's candidates (select_window()).
  void prepare(int v, const RowColumns& row) const;
  void select_window(int v, const RowColumns& row) const;

  // Finds the measurement's candidate and merges the measurement into it if the merge rule
  // allows. Returns whether it did.
  DF_INLINE bool merge(const Measurement& me, const RowColumns& row) const;
  // Merges the measurement into the candidate rendered at `px` if the merge rule allows it.
  inline bool try_merge(size_t px, const Measurement& me) const;
  // Merges into the candidate rendered at `px`: (p_f, L_f), the merge rule's result, with normal
  // n_f.
  inline void merge_into_candidate(size_t px, const Eigen::Vector3f& p_f, const Sym3f& L_f,
                                   const Eigen::Vector3f& n_f, const Measurement& me) const;
  // The candidate in the window around the measurement's pixel, its own excluded, nearest to it
  // in its metric, as the candidates stand now: its pixel, -1 if none.
  int32_t nearest_in_window(const Measurement& me) const;

  // Counts a visibility violation on the front-most point at the measurement's pixel if the
  // camera saw through it (sees_through()). Returns whether it did.
  DF_INLINE bool count_violation(const Measurement& me) const;
  // Whether an existing point in the (2 cr + 1)^2 window around the measurement's pixel lies
  // within the redundancy gate of the measurement.
  bool explained(const Measurement& me) const;

  const MeasurementImage& m_;
  const ColorImage* color_;
  uint32_t frame_id_;
  const SensorModel& model_;
  ModelProjection& proj_;
  CameraInWorld camera_;
  int cr_;
  float range_fraction_;
  float redundancy_gate2_;  // squared Mahalanobis distance; 0: off
  int redundancy_min_merges_;
};

FrameFusion::Measurement FrameFusion::measurement(const RowColumns& row, int u, int v) const {
  const size_t i = static_cast<size_t>(v) * m_.width + u;
  return {u,
          v,
          i,
          row.measurement.position[u],
          row.measurement.normal[u],
          row.measurement.information[u],
          m_.z[i],
          row.range_m[u],
          color_ ? &color_->rgb[3 * i] : nullptr};
}

void FrameFusion::prepare(int v, const RowColumns& row) const {
  const size_t i0 = static_cast<size_t>(v) * m_.width;
  prepare_row({m_.x.data() + i0, m_.y.data() + i0, m_.z.data() + i0},
              {m_.nx.data() + i0, m_.ny.data() + i0, m_.nz.data() + i0}, camera_, model_,
              proj_.candidate_columns(i0), m_.width, row);
}

void FrameFusion::select_window(int v, const RowColumns& row) const {
  const int W = m_.width;
  auto at = [&](int u) { row.window_px[u] = nearest_in_window(measurement(row, u, v)); };
  if (v == 0 || v == m_.height - 1 || W < 3) {
    for (int u = 0; u < W; ++u) at(u);
    return;
  }
  select_window_3x3(proj_.candidate_columns(0), static_cast<size_t>(v) * W, W, row);
  at(0);
  at(W - 1);
}

bool FrameFusion::merge(const Measurement& me, const RowColumns& row) const {
  // The candidate at this very pixel (ModelProjection::render()) first; only if it is missing or
  // does not merge, the other candidate in the window nearest in the measurement's own metric (its
  // information L, which weighs depth less than the lateral offset: by plain distance the
  // neighbour whose error matches the measurement's noise would win). Searching the window first
  // would merge the measurement with its neighbour's point and leave its own pixel's point
  // unrefined. The merge with the pixel's own candidate as its columns stood before this row was
  // fused was worked out in prepare_row(); if a measurement of this row has refined that candidate
  // since, the merge is worked out again. A 3x3 window's candidate was chosen on the candidates as
  // they stood before this row too (select_window()); if it does not merge, the one nearest as
  // they stand now gets a try, for this row's merges may have moved it. (Without that second try
  // a sparse cloud seen from nearer grows layers:
  // Fuser.NearViewsRefineASparseCloudWithoutSpreadingIt.) Other windows are searched as they
  // stand now.
  const ModelProjection& proj = proj_;
  const size_t i = me.pixel;
  if (proj.has_candidate(i) && proj.merged_in_row(i) == me.v) {
    if (try_merge(i, me)) return true;
  } else if (proj.has_candidate(i) && row.merges[me.u]) {
    merge_into_candidate(i, row.merged_position[me.u], proj.candidate_information(i) + me.L,
                         row.merged_normal[me.u], me);
    return true;
  }
  if (cr_ == 0) return false;
  const int32_t chosen = cr_ == 1 ? row.window_px[me.u] : nearest_in_window(me);
  if (chosen >= 0 && try_merge(chosen, me)) return true;
  if (chosen < 0 || cr_ != 1) return false;
  const int32_t now = nearest_in_window(me);
  return now >= 0 && now != chosen && try_merge(now, me);
}

bool FrameFusion::try_merge(size_t px, const Measurement& me) const {
  Eigen::Vector3f p_f;
  Sym3f L_f;
  if (!merge_rule(proj_.candidate_position(px), proj_.candidate_information(px), me.p_w, me.L,
                  &p_f, &L_f))
    return false;
  const Eigen::Vector3f n_f = running_mean_normal(static_cast<float>(proj_.candidate_merges(px)),
                                                  proj_.candidate_normal(px), me.n_w);
  merge_into_candidate(px, p_f, L_f, n_f, me);
  return true;
}

void FrameFusion::merge_into_candidate(size_t px, const Eigen::Vector3f& p_f, const Sym3f& L_f,
                                       const Eigen::Vector3f& n_f, const Measurement& me) const {
  PointArrays& a = proj_.candidate_points(px);
  const size_t j = proj_.candidate_index(px);
  refine_point(a, j, p_f, L_f, n_f, me.rgb, frame_id_);
  proj_.record_merge(px, p_f, L_f, n_f, a.state[j].merges, me.v);
}

int32_t FrameFusion::nearest_in_window(const Measurement& me) const {
  float best_d2 = std::numeric_limits<float>::infinity();
  int32_t best_px = -1;
  any_in_window(me.u, me.v, cr_, m_.width, m_.height, [&](size_t px) {
    consider_candidate(px != me.pixel && proj_.has_candidate(px), static_cast<int32_t>(px),
                       proj_.candidate_position(px), me.p_w, me.L, &best_d2, &best_px);
    return false;
  });
  return best_px;
}

bool FrameFusion::count_violation(const Measurement& me) const {
  // Only the front-most point, and only if it lies in front of the measurement.
  if (proj_.empty_at(me.pixel) || !(proj_.depth_at(me.pixel) < me.z_m)) return false;
  uint32_t j;
  PointArrays& a = proj_.front_points(me.pixel, &j);
  if (!sees_through(camera_.t, a.position(j), a.normal(j), me.p_w, me.n_w, me.range_m,
                    range_fraction_))
    return false;
  a.state[j].violations = saturating_increment(a.state[j].violations);
  return true;
}

bool FrameFusion::explained(const Measurement& me) const {
  // The merge count as it is now: a merge earlier in this frame counts.
  const ModelProjection& proj = proj_;
  return any_in_window(me.u, me.v, cr_, m_.width, m_.height, [&](size_t px) {
    return proj.has_candidate(px) && proj.candidate_merges(px) >= redundancy_min_merges_ &&
           mahalanobis2(Eigen::Vector3f(proj.candidate_position(px) - me.p_w), me.L) <=
               redundancy_gate2_;
  });
}

void FrameFusion::rows(int v0, int v1, int g0, int g1, RowScratch* scratch, PointArrays* added,
                       FusionStats* total) const {
  // The paper's loop over the pixels: each measurement merges into its candidate, or else counts
  // a visibility violation on the point it saw through and, unless the map already explains it
  // (the redundancy gate), becomes a new point. Counted here, added to *total at the end: the
  // loop's byte stores (flags, colours) may alias *total, which would cost a load and a store per
  // count.
  FusionStats counts;
  const RowColumns row = scratch->columns();
  const size_t W = static_cast<size_t>(m_.width);
  int gathered = g0;  // rows [g0, gathered) are gathered
  for (int v = v0; v < v1; ++v) {
    const int g = std::min(g1, v + cr_ + 1);
    if (gathered < g) {
      proj_.gather_candidates(gathered * W, g * W);
      gathered = g;
    }
    prepare(v, row);
    if (cr_ == 1) select_window(v, row);
    for (int u = 0; u < m_.width; ++u) {
      if (!m_.valid[static_cast<size_t>(v) * W + u]) continue;
      ++counts.measurements;
      const Measurement me = measurement(row, u, v);
      if (merge(me, row)) {
        ++counts.merged;
        continue;
      }
      if (count_violation(me)) ++counts.violations;
      // Not merged, but an existing point is within the measurement's own (scaled) ellipsoid: the
      // surface there is already in the map, and a new point would only add a layer.
      if (redundancy_gate2_ > 0.0f && explained(me)) {
        ++counts.redundant;
        continue;
      }
      added->push_back(me.p_w, new_point_state(me.L, me.n_w, me.rgb, frame_id_));
      ++counts.added;
    }
  }
  add_stats(counts, total);
}

// The bands' new points as runs of neighbours that share a chunk, in order: a chunk is looked up
// once a run, not once a point.
void find_runs(const PointArrays* bands, int band_count, const PointMap& map,
               std::vector<PointRun>* runs) {
  runs->clear();
  for (int b = 0; b < band_count; ++b) {
    const PointArrays& added = bands[b];
    for (size_t i = 0; i < added.size(); ++i) {
      const ChunkKey key = map.key_for(added.position_m[i]);
      if (runs->empty() || runs->back().band != b || runs->back().key != key)
        runs->push_back({key, b, i, i});
      runs->back().end = i + 1;
    }
  }
}

// Appends the bands' new points to their chunks, in order, each chunk first given room for all it
// takes. A chunk grows by an eighth at a time (PointArrays::push_back), so a chunk that one view
// fills from empty (a scan's first frame, a room entered) would otherwise be copied dozens of times
// over.
void add_points(const PointArrays* bands, const std::vector<PointRun>& runs, uint32_t frame_id,
                PointMap* map, std::unordered_map<ChunkKey, size_t, ChunkKeyHash>* per_chunk) {
  per_chunk->clear();
  for (const PointRun& run : runs) (*per_chunk)[run.key] += run.end - run.begin;
  for (const auto& [key, count] : *per_chunk) {
    Chunk& chunk = map->get_or_create(key);
    chunk.last_touched_frame = chunk.last_seen_frame = frame_id;
    chunk.dirty = true;
    const size_t size = chunk.points().size();
    if (chunk.points().position_m.capacity() >= size + count) continue;
    // Still geometric: a chunk that takes a few points every frame is not copied every frame.
    chunk.points_for_write().reserve(std::max(size + count, size + size / 8 + 16));
  }
  for (const PointRun& run : runs) {
    const PointArrays& added = bands[run.band];
    PointArrays& points = map->get_or_create(run.key).points_for_write();
    for (size_t i = run.begin; i < run.end; ++i) points.push_back(added.position_m[i], added.state[i]);
  }
}

}  // namespace

FusionStats Fuser::fuse(const MeasurementImage& m, const ColorImage* color, const Pose& T_world_cam,
                        uint32_t frame_id, PointMap* map) {
  const SensorModel model(sensor_config_, m.intrinsics);

  // Existing points near this frame's measurements, rendered into its camera.
  ModelProjection& proj = *projection_;
  proj.set_threads(config_.threads);
  proj.select_chunks_to_fuse(*map, m, T_world_cam, 0.1f);
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
  // Room for each band's every pixel, kept from frame to frame: grown an eighth at a time, a
  // scan's first frame would copy its bands dozens of times over (as add_points() says).
  const size_t W = static_cast<size_t>(m.width);
  if (H > 8 * r) {
    added[0].reserve(W * static_cast<size_t>(h - r));
    added[1].reserve(W * static_cast<size_t>(H - h - r));
    added[2].reserve(W * static_cast<size_t>(2 * r));
    run_pair(
        config_.threads,
        [&] { frame.rows(0, h - r, 0, h - r + cr, &row[0], &added[0], &stats[0]); },
        [&] { frame.rows(h + r, H, h + r - cr, H, &row[1], &added[1], &stats[1]); });
    frame.rows(h - r, h + r, h - r + cr, h + r - cr, &row[0], &added[2], &stats[2]);
  } else {
    added[0].reserve(W * static_cast<size_t>(H));
    frame.rows(0, H, 0, H, &row[0], &added[0], &stats[0]);
  }
  FusionStats total;
  for (int b = 0; b < 3; ++b) add_stats(stats[b], &total);
  find_runs(added, 3, *map, &scratch_->runs);
  add_points(added, scratch_->runs, frame_id, map, &scratch_->added_per_chunk);

  // The chunks this frame observed: eviction keeps recently seen chunks, checkpoints write
  // changed ones.
  for (Chunk* c : proj.chunks()) {
    c->last_touched_frame = c->last_seen_frame = frame_id;
    c->dirty = true;
  }
  return total;
}

size_t postfilter(PointMap* map) {
  size_t removed = 0;
  std::vector<uint8_t> keep;
  map->for_each_chunk([&](const ChunkKey&, Chunk& c) {
    const PointArrays& a = c.points();
    keep.resize(a.size());
    bool any = false;
    for (size_t i = 0; i < a.size(); ++i) {
      keep[i] = a.state[i].violations <= a.state[i].merges;
      any |= !keep[i];
    }
    if (any) {
      removed += c.points_for_write().compact(keep);
      c.dirty = true;
    }
  });
  return removed;
}

}  // namespace depthfuse
