// Internal: the map rendered into a camera. Fusion and registration find a measurement's
// neighbours here instead of searching the cloud: only chunks near the frame's own measurements
// are projected, so the cost follows the frame, not the map.
#pragma once

#include <cstdint>
#include <limits>
#include <vector>

#include "depthfuse/measurement.hpp"
#include "depthfuse/point_map.hpp"
#include "depthfuse/registration.hpp"
#include "depthfuse/sensor_model.hpp"
#include "fusion_columns.hpp"
#include "geometry.hpp"

#include <cmath>
#include <cstring>

namespace depthfuse {

constexpr uint32_t kNoPixel = ~uint32_t{0};

// The pixel (row-major index) of a camera-frame point, or kNoPixel where it lies behind the camera
// or outside the image. Without branches, so that a loop over a block of points vectorises; rounds
// without libm.
DF_INLINE uint32_t pixel_index(float x, float y, float z, float fx, float fy, float cx, float cy,
                               int width, int height) {
  const float inv_z = 1.0f / z;  // inf or nonsense where z <= 1e-3: masked below
  const float fu = fx * x * inv_z + cx + 0.5f, fv = fy * y * inv_z + cy + 0.5f;
  const bool inside = (z > 1e-3f) & (fu >= 0.0f) & (fv >= 0.0f) &
                      (fu < static_cast<float>(width)) & (fv < static_cast<float>(height));
  // Outside, fu and fv may be anything: zero them before converting.
  const int32_t u = static_cast<int32_t>(inside ? fu : 0.0f);
  const int32_t v = static_cast<int32_t>(inside ? fv : 0.0f);
  return inside ? static_cast<uint32_t>(v * width + u) : kNoPixel;
}

// The squared distance, in pixels, from a camera-frame point's projection to the centre of its
// pixel (pixel_index()); only meaningful where that is not kNoPixel.
DF_INLINE float pixel_offset2(float x, float y, float z, float fx, float fy, float cx, float cy) {
  const float inv_z = 1.0f / z;
  const float fu = fx * x * inv_z + cx, fv = fy * y * inv_z + cy;
  // The centre of pixel u is u itself (pixel_index() rounds fu + 0.5 down).
  const float du = fu - static_cast<float>(static_cast<int32_t>(fu + 0.5f));
  const float dv = fv - static_cast<float>(static_cast<int32_t>(fv + 0.5f));
  return du * du + dv * dv;
}

// The keys of the chunks a frame sees from T_world_cam, existing or not, sorted and each once:
// those its measurements (sampled every `stride` pixels) and, if in_front, the stretch of each ray
// just in front of the surface (0.9 to 1.0 of the range, where a seen-through point would be) fall
// in, each dilated where a point lies within margin_m of a chunk face. `near` is scratch.
void frame_chunk_keys(const PointMap& map, const MeasurementImage& m, const Pose& T_world_cam,
                      float margin_m, int stride, std::vector<ChunkKey>* keys,
                      std::vector<ChunkKey>* near, bool in_front = true);

class ModelProjection {
 public:
  // The chunks of frame_chunk_keys() that exist and hold points, for render_surface(): only read.
  void select_chunks(const PointMap& map, const MeasurementImage& m, const Pose& T_world_cam,
                     float margin_m, int stride = 8);
  // The same for render() and fusion, which changes their points: each chunk's arrays are taken
  // for writing here, once (Chunk::points_for_write()), so that the per-pixel accessors need not.
  void select_chunks_to_fuse(PointMap& map, const MeasurementImage& m, const Pose& T_world_cam,
                             float margin_m, int stride = 8);

  // Threads for render() and render_surface(): 1, or 2 (each half of the points renders into its
  // own buffers, combined after). The results do not depend on it.
  void set_threads(int threads) { threads_ = threads; }

  // Projects the points of the selected chunks into the camera at T_world_cam, the camera of the
  // frame's measurements. Per pixel it keeps the front-most point (a z-buffer: visibility) and
  // fusion's merge candidate: of the points within the measurement's axial reach (`model`'s
  // sqrt(lambda2) sigma), the one that projects nearest the pixel's centre; where there is none,
  // the point nearest the measured depth. Where earlier frames left several layers of points over
  // a pixel, the front-most point is often not the one the measurement belongs to; and where one
  // surface has several points over a pixel, the one nearest in depth is the one whose error
  // matches the measurement's noise. `measured` has the size of its intrinsics (backproject()).
  void render(const Pose& T_world_cam, const MeasurementImage& measured, const SensorModel& model);

  // Registration's model, instead of render(): per pixel, the confidence-weighted mean (weight
  // 1 + merges) of the rendered points within band_m behind the front-most one. Registration aligns
  // to this consensus surface: the nearest point alone is biased towards the camera wherever the
  // cloud still has several layers (poorly registered frames), and ICP would pull every camera
  // towards itself. Two passes: the front depth, then the sums. (A single pass whose band follows
  // the front as points stream in leaks farther layers into the mean, and the poses come out worse:
  // docs/history/results-sessions-1-33.md.) The result goes to *view.
  void render_surface(const Pose& T_world_cam, const CameraIntrinsics& K, float band_m,
                      SurfaceView* view);

  // The front-most point at a pixel (render()), read from its z-buffer key.
  bool empty_at(size_t pixel) const { return pixel_keys_[pixel].front == kNoKey; }
  float depth_at(size_t pixel) const { return key_value(pixel_keys_[pixel].front); }
  // The front-most point's chunk and index (a pixel that is not empty_at()). Fusion needs it only
  // where a measurement does not merge, so it is looked up here rather than for every pixel.
  PointArrays& front_points(size_t pixel, uint32_t* index) const {
    int32_t slot;
    locate(static_cast<uint32_t>(pixel_keys_[pixel].front), id_bits_, &slot, index);
    return *arrays_[slot];
  }

  // The merge candidate at a pixel (render() with measurements only). gather_candidates() finds it
  // for a range of pixels, and must have run on a pixel before these are read there. Its world
  // position, information, normal and merge count are copied pixel-ordered (CandidateColumns), so
  // that neighbourhood searches and vectorised loops read contiguous memory. Fusion gathers a row
  // just before it works on it: the points it then refines are still in the cache.
  void gather_candidates(size_t begin, size_t end);
  bool has_candidate(size_t pixel) const { return cand_slot_[pixel] >= 0; }
  Eigen::Vector3f candidate_position(size_t pixel) const { return cand_point().position[pixel]; }
  PointArrays& candidate_points(size_t pixel) const { return *arrays_[cand_slot_[pixel]]; }
  uint32_t candidate_index(size_t pixel) const { return cand_index_[pixel]; }
  // The candidate's information matrix, pixel-ordered like its position (see record_merge()).
  Sym3f candidate_information(size_t pixel) const { return cand_point().information[pixel]; }
  // The candidate's merge count now, this frame's merges included.
  uint16_t candidate_merges(size_t pixel) const { return cand_merges_[pixel]; }
  Eigen::Vector3f candidate_normal(size_t pixel) const { return cand_point().normal[pixel]; }
  // The same columns from `pixel` on, for loops over a row.
  CandidateColumns candidate_columns(size_t pixel) const {
    return {cand_point().from(pixel), cand_merges_.data() + pixel, cand_slot_.data() + pixel};
  }
  // Starts loading the candidate's position and state at a pixel into the cache (a hint, no effect
  // on results). Loops over pixels call it a few pixels ahead.
  __attribute__((always_inline)) void prefetch_candidate(size_t pixel) const {
    const int32_t slot = cand_slot_[pixel];
    if (slot >= 0) {
      const PointArrays& a = *arrays_[slot];
      const uint32_t i = cand_index_[pixel];
      __builtin_prefetch(a.position_m.data() + i);
      // A 48-byte record can straddle two cache lines: fetch both ends.
      const char* state = reinterpret_cast<const char*>(a.state.data() + i);
      __builtin_prefetch(state);
      __builtin_prefetch(state + sizeof(PointState) - 1);
    }
  }
  static constexpr size_t kPrefetchPixels = 16;

  // The image row whose fusion last merged a measurement with the candidate at a pixel, or -1 if
  // none has this frame.
  int merged_in_row(size_t pixel) const { return merged_row_[pixel]; }
  // Records that the candidate at a pixel was refined to (p_w, L) with normal n, now merged
  // `merges` times, while fusing image row `row`. Its columns follow, so that a later measurement
  // of the same frame merges with the point as it is now: a point may merge with several
  // measurements of one frame, as in the paper's loop over pixels. (A point is the candidate of one
  // pixel at most, so per-pixel columns suffice.)
  void record_merge(size_t pixel, const Eigen::Vector3f& p_w, const Sym3f& L,
                    const Eigen::Vector3f& n, uint16_t merges, int row) {
    set_candidate_columns(pixel, p_w, L, n, merges);
    merged_row_[pixel] = row;
  }

  size_t rendered_points() const { return rendered_; }
  // The chunks select_chunks_to_fuse() selected (empty after select_chunks()).
  const std::vector<Chunk*>& chunks() const { return chunks_; }

 private:
  // A pixel's z-buffer entries as 64-bit keys, (key bits << 32) | point id, so that one integer
  // comparison keeps the minimum (non-negative floats order like their bit patterns). kNoKey: none.
  static constexpr uint64_t kNoKey = ~uint64_t{0};
  static float key_value(uint64_t key) {
    const uint32_t bits = static_cast<uint32_t>(key >> 32);
    float f;
    std::memcpy(&f, &bits, sizeof(f));
    return f;
  }
  struct PixelKeys {
    uint64_t front;     // key: depth in the camera
    uint64_t cand;      // key: the candidate's rank (render_points())
    float measured_z;   // the frame's depth at this pixel, +inf = none
    float band_m;       // candidates within this depth of measured_z are ranked by pixel offset
  };
  using SurfaceSum = SurfaceView::Pixel;  // summed, then normalised
  size_t render_points(const Pose& T_world_cam, const CameraIntrinsics& K, size_t chunk_begin,
                       size_t chunk_end, PixelKeys* keys) const;
  size_t render_front_depth(const Pose& T_world_cam, const CameraIntrinsics& K, size_t chunk_begin,
                            size_t chunk_end, float* front) const;
  void sum_surface(const Pose& T_world_cam, const CameraIntrinsics& K, float band_m,
                   size_t chunk_begin, size_t chunk_end, SurfaceSum* sum) const;
  // The candidates' points (CandidateColumns::point), from pixel 0.
  PointColumns<const float> cand_point() const { return cand_columns_; }
  // The candidate columns at a pixel: world position, information, normal, merge count.
  void set_candidate_columns(size_t pixel, const Eigen::Vector3f& p_w, const Sym3f& L,
                             const Eigen::Vector3f& n, uint16_t merges) {
    cand_columns_.set(pixel, p_w, L, n);
    cand_merges_[pixel] = merges;
  }
  // gather_candidates()' first pass: cand_slot_ and cand_index_ from the keys, merged_row_
  // cleared. Without branches and through plain pointers, so that it vectorises.
  DF_VECTOR_CLONES void locate_candidates(size_t begin, size_t end);
  // Sizes the point ids to the selected chunks (id_bits_).
  void size_ids();
  // The chunk where the second thread's half of the points starts.
  size_t split_chunk() const;
  // Point id back to chunk slot and index, for ids of id_bits index bits (id_bits_).
  static DF_INLINE void locate(uint32_t id, int id_bits, int32_t* slot, uint32_t* index) {
    *slot = static_cast<int32_t>(id >> id_bits);
    *index = id & static_cast<uint32_t>((uint64_t{1} << id_bits) - 1);
  }

  std::vector<ChunkKey> keys_, near_;   // scratch
  std::vector<Chunk*> chunks_;          // selected to fuse: existing, non-empty chunks
  // The selected chunks' points, in their order (slots). Written only through the chunks
  // select_chunks_to_fuse() took for writing; select_chunks() fills it for reading alone.
  std::vector<PointArrays*> arrays_;
  // A point's id in the z-buffer keys: (its chunk's slot in arrays_ << id_bits_) | its index, so
  // that ids order like (slot, index) and locate() is two bit operations.
  int id_bits_ = 0;
  std::vector<PixelKeys> pixel_keys_;   // per pixel: render()'s result
  std::vector<PixelKeys> pixel_keys_2_; // the second thread's, combined into the first
  int threads_ = 1;
  std::vector<int32_t> cand_slot_;      // per pixel, once gathered: index into arrays_, -1 = none
  std::vector<uint32_t> cand_index_;    // per pixel, once gathered: point index within the chunk
  std::vector<float> front_depth_;      // render_surface(), per pixel: z of the front-most point
  std::vector<float> front_depth_2_;    // render_surface(): the second half's
  // Per pixel: the candidate's point (CandidateColumns::point) and merge count.
  std::vector<float> cand_point_[PointColumns<float>::kColumns];
  // The view over cand_point_, laid once when render() sizes it: the per-pixel accessors then load
  // one column pointer each, as they would from the vectors themselves.
  PointColumns<float> cand_columns_{};
  std::vector<uint16_t> cand_merges_;
  std::vector<int32_t> merged_row_;     // per pixel: see merged_in_row()
  size_t rendered_ = 0;
  std::vector<SurfaceSum> surface_2_;   // render_surface(): the second thread's sums
};

}  // namespace depthfuse
