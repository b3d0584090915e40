#include "model_projection.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <tuple>

#include "parallel.hpp"

namespace depthfuse {

void frame_chunk_keys(const PointMap& map, const MeasurementImage& m, const Pose& T_world_cam,
                      float margin_m, int stride, std::vector<ChunkKey>* keys,
                      std::vector<ChunkKey>* near, bool in_front) {
  keys->clear();
  const Eigen::Matrix3f R = T_world_cam.linear().cast<float>();
  const Eigen::Vector3f t = T_world_cam.translation().cast<float>();
  // Most repeats are kept out of the sort; the sort and unique below remove the rest.
  SeenChunkKeys listed;
  // One sample per stride x stride block, not at the same place in every block: the column moves
  // with the block's row and the row with the block's column (by 3 each time, which runs through
  // all eight places when the stride is 8). An object narrower than the stride then still gets
  // sampled if it spans a few blocks in the other direction; with a fixed grid a pole between two
  // sampled columns went unseen, its chunk unselected, and every view added it again.
  const int s = std::max(1, stride);
  for (int bv = 0; bv * s < m.height; ++bv) {
    for (int bu = 0; bu * s < m.width; ++bu) {
      const int u = bu * s + (3 * bv) % s, v = bv * s + (3 * bu) % s;
      if (u >= m.width || v >= m.height) continue;
      const size_t i = static_cast<size_t>(v) * m.width + u;
      if (!m.valid[i]) continue;
      const Eigen::Vector3f p_c(m.x[i], m.y[i], m.z[i]);
      for (float f : {1.0f, 0.95f, 0.9f}) {
        if (f < 1.0f && !in_front) break;
        near->clear();
        map.keys_near(R * (f * p_c) + t, margin_m, near);
        for (const ChunkKey& k : *near)
          if (!listed.seen(k)) keys->push_back(k);
      }
    }
  }
  std::sort(keys->begin(), keys->end());
  keys->erase(std::unique(keys->begin(), keys->end()), keys->end());
}

void ModelProjection::select_chunks(const PointMap& map, const MeasurementImage& m,
                                    const Pose& T_world_cam, float margin_m, int stride) {
  frame_chunk_keys(map, m, T_world_cam, margin_m, stride, &keys_, &near_);
  chunks_.clear();
  arrays_.clear();
  for (const ChunkKey& k : keys_) {
    const Chunk* c = map.find(k);
    // Never written through: only render_surface() reads them.
    if (c && !c->points().empty()) arrays_.push_back(const_cast<PointArrays*>(&c->points()));
  }
}

void ModelProjection::select_chunks_to_fuse(PointMap& map, const MeasurementImage& m,
                                            const Pose& T_world_cam, float margin_m, int stride) {
  frame_chunk_keys(map, m, T_world_cam, margin_m, stride, &keys_, &near_);
  chunks_.clear();
  arrays_.clear();
  for (const ChunkKey& k : keys_) {
    Chunk* c = map.find(k);
    if (!c || c->points().empty()) continue;
    chunks_.push_back(c);
    arrays_.push_back(&c->points_for_write());
  }
}

namespace {

constexpr uint32_t kInfBits = 0x7f800000u;  // bit pattern of +inf

inline uint32_t float_bits(float f) {
  uint32_t b;
  std::memcpy(&b, &f, sizeof(b));
  return b;
}

// The camera that render() and render_surface() project into: world to pixel.
struct PixelProjector {
  Eigen::Matrix3f R;
  Eigen::Vector3f t;
  float fx, fy, cx, cy;
  int width, height;

  PixelProjector(const Pose& T_world_cam, const CameraIntrinsics& K) {
    const Pose T_cam_world = T_world_cam.inverse();
    R = T_cam_world.linear().cast<float>();
    t = T_cam_world.translation().cast<float>();
    fx = static_cast<float>(K.fx);
    fy = static_cast<float>(K.fy);
    cx = static_cast<float>(K.cx);
    cy = static_cast<float>(K.cy);
    width = K.width;
    height = K.height;
  }

  // Pixel index, camera depth and squared offset from the pixel's centre (pixel_offset2()) of each
  // point in a block; kNoPixel where it falls outside. Projecting a block first and updating the
  // pixels after lets the random pixel accesses be prefetched and overlap, instead of waiting on
  // each one in turn. The whole block is projected at once, so that it vectorises (a loop of a
  // fixed count; the points first copied out to one array per coordinate); entries from `count`
  // on are padding.
  static constexpr size_t kBlock = 64;
  DF_VECTOR_CLONES void project_block(const Eigen::Vector3f* pos, size_t count, uint32_t* pixel,
                                      float* depth, float* offset2) const {
    float X[kBlock], Y[kBlock], Z[kBlock];
    for (size_t i = 0; i < kBlock; ++i) {
      const bool real = i < count;  // padding: z = 0 falls outside
      X[i] = real ? pos[i].x() : 0.0f;
      Y[i] = real ? pos[i].y() : 0.0f;
      Z[i] = real ? pos[i].z() : 0.0f;
    }
    const float r00 = R(0, 0), r01 = R(0, 1), r02 = R(0, 2), r10 = R(1, 0), r11 = R(1, 1),
                r12 = R(1, 2), r20 = R(2, 0), r21 = R(2, 1), r22 = R(2, 2);
    const float tx = t.x(), ty = t.y(), tz = t.z();
    DF_IVDEP
    for (size_t i = 0; i < kBlock; ++i) {
      const float x = r00 * X[i] + r01 * Y[i] + r02 * Z[i] + tx;
      const float y = r10 * X[i] + r11 * Y[i] + r12 * Z[i] + ty;
      const float z = r20 * X[i] + r21 * Y[i] + r22 * Z[i] + tz;
      pixel[i] = pixel_index(x, y, z, fx, fy, cx, cy, width, height);
      depth[i] = z;
      offset2[i] = pixel_offset2(x, y, z, fx, fy, cx, cy);
    }
  }
};

// Projects the points of chunks [begin, end) a block at a time and hands each block to
// visit(chunk index, points, first index, count, pixel[], depth[], offset2[]). The visitor
// prefetches what the pixels will touch, then updates them: those random accesses then overlap.
template <typename Visit>
void for_each_block(const std::vector<PointArrays*>& chunks, size_t begin, size_t end,
                    const PixelProjector& cam, Visit&& visit) {
  uint32_t pixel[PixelProjector::kBlock];
  float depth[PixelProjector::kBlock], offset2[PixelProjector::kBlock];
  for (size_t c = begin; c < end; ++c) {
    const PointArrays& a = *chunks[c];
    const size_t count = a.size();
    for (size_t start = 0; start < count; start += PixelProjector::kBlock) {
      const size_t block = std::min(PixelProjector::kBlock, count - start);
      cam.project_block(a.position_m.data() + start, block, pixel, depth, offset2);
      visit(c, a, start, block, pixel, depth, offset2);
    }
  }
}

template <typename T>
inline void prefetch_pixels(const T* buffer, const uint32_t* pixel, size_t block) {
  for (size_t i = 0; i < block; ++i) {
    if (pixel[i] != kNoPixel) __builtin_prefetch(buffer + pixel[i], 1);
  }
}

}  // namespace

size_t ModelProjection::render_points(const Pose& T_world_cam, const CameraIntrinsics& K,
                                      size_t chunk_begin, size_t chunk_end, PixelKeys* keys) const {
  size_t rendered = 0;
  for_each_block(arrays_, chunk_begin, chunk_end, PixelProjector(T_world_cam, K),
                 [&](size_t c, const PointArrays&, size_t start, size_t block, const uint32_t* pixel,
                     const float* depth, const float* offset2) {
    prefetch_pixels(keys, pixel, block);
    const uint64_t base = (uint64_t{c} << id_bits_) + start;
    for (size_t i = 0; i < block; ++i) {
      if (pixel[i] == kNoPixel) continue;
      PixelKeys& k = keys[pixel[i]];
      ++rendered;
      const uint64_t id = base + i;
      // Branch-free minimum: which point wins a pixel is unpredictable.
      k.front = std::min((uint64_t{float_bits(depth[i])} << 32) | id, k.front);
      // The merge candidate: among the points within the measurement's axial reach, the one that
      // projects nearest the pixel's centre (ranks 0 to 0.5); failing that, the one nearest in
      // depth (ranks from 1). Ranking points on the measured surface by depth too would pick the
      // one whose own error happens to match the measurement's noise, and neighbouring points
      // would drift apart. Pixels without a measurement have measured_z = +inf: their keys stay
      // at +inf.
      const float dz = std::abs(depth[i] - k.measured_z);
      const float rank = dz <= k.band_m ? offset2[i] : 1.0f + dz;
      const uint64_t cand = (uint64_t{float_bits(rank)} << 32) | id;
      k.cand = std::min(cand, k.cand);
    }
  });
  return rendered;
}

void ModelProjection::size_ids() {
  size_t largest = 0;
  for (const PointArrays* a : arrays_) largest = std::max(largest, a->size());
  id_bits_ = 0;
  while (id_bits_ < 64 && (uint64_t{largest} >> id_bits_) != 0) ++id_bits_;
  // More chunks than the ids can tell apart would mean billions of points in view: render a
  // prefix only. (The last id stays below kNoKey's low half.)
  const uint64_t max_chunks = id_bits_ >= 32 ? 0 : (uint64_t{1} << (32 - id_bits_)) - 1;
  if (arrays_.size() > max_chunks) arrays_.resize(max_chunks);
  if (chunks_.size() > max_chunks) chunks_.resize(max_chunks);
}

size_t ModelProjection::split_chunk() const {
  uint64_t total = 0;
  for (const PointArrays* a : arrays_) total += a->size();
  // The first chunk with at least half of the points before it.
  size_t s = 0;
  for (uint64_t before = 0; s < arrays_.size() && before < total / 2; ++s)
    before += arrays_[s]->size();
  return s;
}

void ModelProjection::render(const Pose& T_world_cam, const MeasurementImage& measured,
                             const SensorModel& model) {
  const CameraIntrinsics& K = measured.intrinsics;
  const size_t n = static_cast<size_t>(K.width) * K.height;
  size_ids();

  // Every per-pixel pass below runs on the two halves of the pixels (or of the points), on two
  // threads if there are two; none depends on the thread count.
  const bool two = threads_ > 1 && arrays_.size() > 1;
  pixel_keys_.resize(n);
  pixel_keys_2_.resize(two ? n : 0);
  const float inf = std::numeric_limits<float>::infinity();
  auto clear_keys = [&](PixelKeys* keys, size_t begin, size_t end) {
    for (size_t px = begin; px < end; ++px) {
      PixelKeys& k = keys[px];
      k.front = kNoKey;
      k.cand = kNoKey;
      const bool valid = measured.valid[px];
      k.measured_z = valid ? measured.z[px] : inf;
      k.band_m = valid ? model.axial_reach_m(measured.z[px]) : 0.0f;
    }
  };
  const size_t split = two ? split_chunk() : arrays_.size();
  size_t rendered[2] = {0, 0};
  auto half = [&](int h) {
    const size_t begin = h == 0 ? 0 : split, end = h == 0 ? split : arrays_.size();
    PixelKeys* keys = h == 0 ? pixel_keys_.data() : pixel_keys_2_.data();
    if (h == 0 || two) clear_keys(keys, 0, n);  // each thread clears the buffer it renders into
    rendered[h] = render_points(T_world_cam, K, begin, end, keys);
  };
  run_pair(two ? 2 : 1, [&] { half(0); }, [&] { half(1); });
  rendered_ = rendered[0] + rendered[1];

  // The keys are the result: fusion reads the front-most point from them, and gather_candidates()
  // finds the candidates, a row at a time. Only the two halves need combining.
  if (two) {
    run_halves(threads_, n, [&](size_t begin, size_t end) {
      for (size_t px = begin; px < end; ++px) {
        PixelKeys& k = pixel_keys_[px];
        k.front = std::min(k.front, pixel_keys_2_[px].front);
        k.cand = std::min(k.cand, pixel_keys_2_[px].cand);
      }
    });
  }
  cand_slot_.resize(n);
  cand_index_.resize(n);
  for (std::vector<float>& column : cand_point_) column.resize(n);
  cand_columns_ = PointColumns<float>::over(cand_point_, 0);
  cand_merges_.resize(n);
  merged_row_.resize(n);
}

void ModelProjection::locate_candidates(size_t begin, size_t end) {
  const PixelKeys* keys = pixel_keys_.data();
  int32_t* slot = cand_slot_.data();
  uint32_t* index = cand_index_.data();
  int32_t* merged_row = merged_row_.data();
  const int id_bits = id_bits_;
  DF_IVDEP
  for (size_t px = begin; px < end; ++px) {
    const uint64_t key = keys[px].cand;
    // No candidate, or no measurement at this pixel: the key is +inf or kNoKey.
    const bool none = (key >> 32) >= kInfBits;
    int32_t s;
    locate(static_cast<uint32_t>(key), id_bits, &s, &index[px]);
    slot[px] = none ? -1 : s;
    merged_row[px] = -1;
  }
}

void ModelProjection::gather_candidates(size_t begin, size_t end) {
  // Which point each pixel's candidate is, first for the whole range: the prefetches below need it.
  locate_candidates(begin, end);
  // Each is a random read into the map: prefetching a few pixels ahead turns a chain of cache
  // misses into overlapping ones.
  for (size_t px = begin; px < end; ++px) {
    if (px + kPrefetchPixels < end) prefetch_candidate(px + kPrefetchPixels);
    if (cand_slot_[px] < 0) continue;
    const PointArrays& a = *arrays_[cand_slot_[px]];
    const uint32_t j = cand_index_[px];
    const PointState& st = a.state[j];
    set_candidate_columns(px, a.position_m[j],
                          {st.info_xx, st.info_xy, st.info_xz, st.info_yy, st.info_yz, st.info_zz},
                          {st.nx, st.ny, st.nz}, st.merges);
  }
}

size_t ModelProjection::render_front_depth(const Pose& T_world_cam, const CameraIntrinsics& K,
                                           size_t chunk_begin, size_t chunk_end,
                                           float* front) const {
  size_t rendered = 0;
  for_each_block(arrays_, chunk_begin, chunk_end, PixelProjector(T_world_cam, K),
                 [&](size_t, const PointArrays&, size_t, size_t block, const uint32_t* pixel,
                     const float* depth, const float*) {
    prefetch_pixels(front, pixel, block);
    for (size_t i = 0; i < block; ++i) {
      if (pixel[i] == kNoPixel) continue;
      ++rendered;
      front[pixel[i]] = std::min(front[pixel[i]], depth[i]);
    }
  });
  return rendered;
}

void ModelProjection::sum_surface(const Pose& T_world_cam, const CameraIntrinsics& K, float band_m,
                                  size_t chunk_begin, size_t chunk_end, SurfaceSum* sum) const {
  const float* front = front_depth_.data();
  for_each_block(arrays_, chunk_begin, chunk_end, PixelProjector(T_world_cam, K),
                 [&](size_t, const PointArrays& a, size_t start, size_t block, uint32_t* pixel,
                     const float* depth, const float*) {
    prefetch_pixels(front, pixel, block);
    for (size_t i = 0; i < block; ++i) {  // points behind the surface drop out
      if (pixel[i] != kNoPixel && depth[i] > front[pixel[i]] + band_m)
        pixel[i] = kNoPixel;
    }
    prefetch_pixels(sum, pixel, block);
    for (size_t i = 0; i < block; ++i) {
      if (pixel[i] == kNoPixel) continue;
      const Eigen::Vector3f& p = a.position_m[start + i];
      const PointState& st = a.state[start + i];
      const float w = 1.0f + st.merges;
      SurfaceSum& s = sum[pixel[i]];
      s.x += w * p.x();
      s.y += w * p.y();
      s.z += w * p.z();
      s.nx += w * st.nx;
      s.ny += w * st.ny;
      s.nz += w * st.nz;
      s.w += w;
    }
  });
}

void ModelProjection::render_surface(const Pose& T_world_cam, const CameraIntrinsics& K,
                                     float band_m, SurfaceView* view) {
  const size_t n = static_cast<size_t>(K.width) * K.height;
  // Point ids are not needed here, only the split of the chunks in two halves. There are always
  // two halves, on two threads if there are two, so that the result does not depend on the count.
  // Each thread clears the buffers it renders into; the per-pixel passes that combine the two
  // run on the two halves of the pixels.
  const size_t split = split_chunk();

  // Pass 1: the front-most depth per pixel.
  const float inf = std::numeric_limits<float>::infinity();
  front_depth_.resize(n);
  front_depth_2_.resize(n);
  size_t rendered[2] = {0, 0};
  run_pair(
      threads_,
      [&] {
        std::fill(front_depth_.begin(), front_depth_.end(), inf);
        rendered[0] = render_front_depth(T_world_cam, K, 0, split, front_depth_.data());
      },
      [&] {
        std::fill(front_depth_2_.begin(), front_depth_2_.end(), inf);
        rendered[1] = render_front_depth(T_world_cam, K, split, arrays_.size(), front_depth_2_.data());
      });
  rendered_ = rendered[0] + rendered[1];
  run_halves(threads_, n, [&](size_t begin, size_t end) {
    for (size_t px = begin; px < end; ++px)
      front_depth_[px] = std::min(front_depth_[px], front_depth_2_[px]);
  });

  // Pass 2: the weighted sums of the points within the band behind it.
  const SurfaceSum zero{0, 0, 0, 0, 0, 0, 0};
  view->K = K;
  view->T_world_cam = T_world_cam;
  std::vector<SurfaceSum>& surface = view->pixels;
  surface.resize(n);
  surface_2_.resize(n);
  run_pair(
      threads_,
      [&] {
        std::fill(surface.begin(), surface.end(), zero);
        sum_surface(T_world_cam, K, band_m, 0, split, surface.data());
      },
      [&] {
        std::fill(surface_2_.begin(), surface_2_.end(), zero);
        sum_surface(T_world_cam, K, band_m, split, arrays_.size(), surface_2_.data());
      });
  run_halves(threads_, n, [&](size_t begin, size_t end) {
    for (size_t px = begin; px < end; ++px) {
      SurfaceSum& s = surface[px];
      const SurfaceSum& o = surface_2_[px];
      s.x += o.x;
      s.y += o.y;
      s.z += o.z;
      s.nx += o.nx;
      s.ny += o.ny;
      s.nz += o.nz;
      s.w += o.w;
      if (s.w <= 0.0f) continue;
      const float inv_w = 1.0f / s.w;
      s.x *= inv_w;
      s.y *= inv_w;
      s.z *= inv_w;
      Eigen::Vector3f nn(s.nx, s.ny, s.nz);
      const float len = nn.norm();
      if (len < 0.5f * s.w) {  // normals disagree: no usable plane here
        s.w = 0.0f;
        continue;
      }
      nn /= len;
      s.nx = nn.x();
      s.ny = nn.y();
      s.nz = nn.z();
    }
  });
}

}  // namespace depthfuse
