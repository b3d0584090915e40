#include "depthfuse/store/map_pager.hpp"

#include <malloc.h>

#include <algorithm>
#include <cmath>
#include <tuple>

#include "depthfuse/store/scan_store.hpp"

namespace depthfuse::store {

namespace {

// std::unordered_map node and bucket overhead per chunk, roughly.
constexpr size_t kChunkOverheadBytes = sizeof(Chunk) + sizeof(ChunkKey) + 4 * sizeof(void*);

bool key_less(const ChunkKey& a, const ChunkKey& b) {
  return std::tie(a.x, a.y, a.z) < std::tie(b.x, b.y, b.z);
}

}  // namespace

float distance_to_chunk_m(const PointMap& map, const ChunkKey& key, const Eigen::Vector3f& p) {
  const Eigen::Vector3f lo = map.chunk_origin_m(key);
  const Eigen::Vector3f hi = lo + Eigen::Vector3f::Constant(static_cast<float>(map.chunk_size_m()));
  const Eigen::Vector3f d = (lo - p).cwiseMax(p - hi).cwiseMax(Eigen::Vector3f::Zero());
  return d.norm();
}

size_t MapPager::chunk_bytes(const Chunk& chunk) {
  return chunk.points.memory_bytes() + kChunkOverheadBytes;
}

MapPager::MapPager(const MapPagerConfig& config, ScanStore* store) : config_(config), store_(store) {}

Status MapPager::validate(const MapPagerConfig& c) {
  if (!(c.memory_budget_mib > 0.0)) return invalid_argument("memory_budget_mib must be positive");
  if (!(c.low_watermark_fraction > 0.0 && c.low_watermark_fraction <= 1.0))
    return invalid_argument("low_watermark_fraction must be in (0, 1]");
  if (!(c.evict_distance_m >= 0.0)) return invalid_argument("evict_distance_m must be >= 0");
  if (c.min_age_frames < 0) return invalid_argument("min_age_frames must be >= 0");
  if (!(c.load_margin_m >= 0.0)) return invalid_argument("load_margin_m must be >= 0");
  if (c.load_subsample_px < 1) return invalid_argument("load_subsample_px must be >= 1");
  return Status::ok();
}

Status MapPager::finish_call(Status st) {
  stats_.evicted_chunks = evicted_.size();
  stats_.unloadable_chunks = unloadable_.size();
  if (!st) {
    ++stats_.failures;
    stats_.last_error = st.to_string();
  } else {
    stats_.last_error.clear();
  }
  return st;
}

Status MapPager::prepare(PointMap* map, const Frame& frame, const Pose& T, uint32_t frame_id) {
  if (evicted_.empty()) return Status::ok();  // nothing to bring back: free
  const DepthImage& d = frame.depth;
  const CameraIntrinsics& K = frame.intrinsics;
  if (d.empty() || d.width != K.width || d.height != K.height || !K.valid()) return Status::ok();
  const Eigen::Matrix3f R = T.linear().cast<float>();
  const Eigen::Vector3f t = T.translation().cast<float>();
  const float fx = static_cast<float>(K.fx), fy = static_cast<float>(K.fy);
  const float cx = static_cast<float>(K.cx), cy = static_cast<float>(K.cy);
  const float margin = static_cast<float>(config_.load_margin_m);
  const int step = config_.load_subsample_px;
  keys_.clear();
  // The same samples as the pipeline's chunk selection: the surface point, and the stretch of the
  // ray just in front of it (0.9 .. 1.0 of the range) that visibility checks look at.
  for (int v = step / 2; v < d.height; v += step) {
    for (int u = step / 2; u < d.width; u += step) {
      const float z = d.depth_m[static_cast<size_t>(v) * d.width + u];
      if (!(z > 0.0f) || !std::isfinite(z)) continue;
      const Eigen::Vector3f p_c((u - cx) / fx * z, (v - cy) / fy * z, z);
      for (float f : {1.0f, 0.95f, 0.9f}) map->keys_near(R * (f * p_c) + t, margin, &keys_);
    }
  }
  std::sort(keys_.begin(), keys_.end(), key_less);
  keys_.erase(std::unique(keys_.begin(), keys_.end()), keys_.end());
  keys_.erase(std::remove_if(keys_.begin(), keys_.end(), [&](const ChunkKey& k) { return !evicted_.count(k); }),
              keys_.end());
  return finish_call(load(map, keys_, frame_id));
}

Status MapPager::load_around(PointMap* map, const Eigen::Vector3f& p, double radius_m, uint32_t frame_id) {
  if (evicted_.empty()) return Status::ok();
  const float radius = static_cast<float>(radius_m);
  const int reach = static_cast<int>(std::ceil(radius_m / map->chunk_size_m())) + 1;
  const size_t cube = static_cast<size_t>(2 * reach + 1) * (2 * reach + 1) * (2 * reach + 1);
  keys_.clear();
  if (evicted_.size() < cube) {
    for (const ChunkKey& k : evicted_)
      if (distance_to_chunk_m(*map, k, p) <= radius) keys_.push_back(k);
  } else {
    const ChunkKey c = map->key_for(p);
    ChunkKey k;
    for (k.x = c.x - reach; k.x <= c.x + reach; ++k.x)
      for (k.y = c.y - reach; k.y <= c.y + reach; ++k.y)
        for (k.z = c.z - reach; k.z <= c.z + reach; ++k.z)
          if (evicted_.count(k) && distance_to_chunk_m(*map, k, p) <= radius) keys_.push_back(k);
  }
  std::sort(keys_.begin(), keys_.end(), key_less);
  return finish_call(load(map, keys_, frame_id));
}

Status MapPager::load(PointMap* map, const std::vector<ChunkKey>& keys, uint32_t frame_id) {
  Status first_error;
  for (const ChunkKey& k : keys) {
    auto stored = store_->read_chunk(k, /*include_staged=*/true);
    evicted_.erase(k);
    if (!stored) {
      // Not found: nothing to load. Damaged or unreadable: it stays in the file untouched (a
      // chunk fusion creates at that key replaces it at the next checkpoint).
      if (stored.status().code() != StatusCode::kNotFound) {
        unloadable_.insert(k);
        if (first_error) first_error = stored.status().with_context("loading an evicted chunk");
      }
      continue;
    }
    Chunk loaded = std::move(stored->chunk);
    if (Chunk* resident = map->find(k)) {
      // Fusion created the chunk while it was evicted (prepare() was skipped or the pose jumped):
      // keep both sets of points.
      loaded.points.append(resident->points);
      loaded.last_touched_frame = std::max(loaded.last_touched_frame, resident->last_touched_frame);
      loaded.dirty = true;
      ++stats_.load_collisions;
    }
    map->insert(k, std::move(loaded));
    loaded_at_[k] = frame_id;
    ++stats_.total_loaded;
  }
  return first_error;
}

Status MapPager::update(PointMap* map, const Eigen::Vector3f& camera_position_m, uint32_t frame_id) {
  return finish_call(evict(map, camera_position_m, frame_id));
}

Status MapPager::evict(PointMap* map, const Eigen::Vector3f& cam, uint32_t frame_id) {
  const size_t budget = static_cast<size_t>(config_.memory_budget_mib * 1024.0 * 1024.0);
  size_t resident = 0;
  map->for_each_chunk([&](const ChunkKey&, const Chunk& c) { resident += chunk_bytes(c); });
  stats_.resident_chunks = map->chunk_count();
  stats_.resident_bytes = resident;
  stats_.unevictable_bytes = 0;
  if (resident <= budget) return Status::ok();
  if (skip_eviction_calls_ > 0) {
    --skip_eviction_calls_;
    return Status::ok();
  }

  candidates_.clear();
  const float keep_distance = static_cast<float>(config_.evict_distance_m);
  const uint32_t min_age = static_cast<uint32_t>(config_.min_age_frames);
  map->for_each_chunk([&](const ChunkKey& k, const Chunk& c) {
    uint32_t used = c.last_touched_frame;
    if (auto it = loaded_at_.find(k); it != loaded_at_.end()) used = std::max(used, it->second);
    if (used >= frame_id) return;  // observed by (or loaded for) this very frame
    const float d = distance_to_chunk_m(*map, k, cam);
    if (d <= keep_distance) return;
    candidates_.push_back({k, used, d, chunk_bytes(c), used + min_age >= frame_id});
  });
  // Least recently used first; among equals, the farthest. The recently seen come last.
  std::sort(candidates_.begin(), candidates_.end(), [](const Candidate& a, const Candidate& b) {
    if (a.last_used_frame != b.last_used_frame) return a.last_used_frame < b.last_used_frame;
    return a.distance_m > b.distance_m;
  });
  // Chunks not seen for min_age_frames go first, down to the low watermark. Only when they do not
  // bring the map under the budget itself do recently seen ones go too (just down to the budget,
  // as the next frames may load them back): the views of the last min_age_frames frames can hold
  // more than the budget (a walk back into mapped rooms loads their full chunks), and the budget
  // must hold anyway. What stays is this frame's chunks and those near the camera.
  const size_t target = static_cast<size_t>(static_cast<double>(budget) * config_.low_watermark_fraction);
  size_t n = 0, freed = 0, recent = 0;
  while (n < candidates_.size() && !candidates_[n].recent && resident - freed > target)
    freed += candidates_[n++].bytes;
  while (n < candidates_.size() && resident - freed > budget) {
    freed += candidates_[n++].bytes;
    ++recent;
  }
  if (resident - freed > budget) stats_.unevictable_bytes = resident - freed - budget;
  if (n == 0) return Status::ok();

  // Changed chunks go to the scan file first, all in one transaction; only then are they dropped.
  std::vector<std::pair<ChunkKey, const Chunk*>> writes;
  for (size_t i = 0; i < n; ++i) {
    const Chunk* c = map->find(candidates_[i].key);
    if (c->dirty) writes.emplace_back(candidates_[i].key, c);
  }
  Status st = store_->stage_chunks(writes);
  if (!st) {
    skip_eviction_calls_ = config_.retry_after_failure_calls;
    return st.with_context("evicting " + std::to_string(n) + " chunks (they stay in memory)");
  }
  stats_.total_written += writes.size();
  for (size_t i = 0; i < n; ++i) {
    const ChunkKey& k = candidates_[i].key;
    const Chunk* c = map->find(k);
    // A clean, empty chunk has nothing in the file and nothing to come back to.
    const bool keep_key = c->dirty || !c->points.empty();
    map->extract(k, nullptr);
    loaded_at_.erase(k);
    unloadable_.erase(k);
    if (keep_key) evicted_.insert(k);
  }
  stats_.total_evicted += n;
  stats_.total_evicted_recent += recent;
  stats_.resident_chunks = map->chunk_count();
  stats_.resident_bytes = resident - freed;
  if (config_.release_memory_to_os) malloc_trim(0);
  return Status::ok();
}

}  // namespace depthfuse::store
