#include "depthfuse/store/map_pager.hpp"

#include <malloc.h>

#include <algorithm>
#include <cmath>

#include "depthfuse/store/scan_store.hpp"

namespace depthfuse::store {

namespace {
// std::unordered_map node and bucket overhead per chunk, roughly.
constexpr size_t kChunkOverheadBytes = sizeof(Chunk) + sizeof(ChunkKey) + 4 * sizeof(void*);
}  // namespace

float distance_to_chunk_m(const PointMap& map, const ChunkKey& key, const Eigen::Vector3f& p) {
  const Eigen::Vector3f lo = map.chunk_origin_m(key);
  const Eigen::Vector3f hi = lo + Eigen::Vector3f::Constant(static_cast<float>(map.chunk_size_m()));
  const Eigen::Vector3f d = (lo - p).cwiseMax(p - hi).cwiseMax(Eigen::Vector3f::Zero());
  return d.norm();
}

double sensor_reach_m(const CameraIntrinsics& K, double max_depth_m) {
  // The longest ray (z = 1) goes through the corner farthest from the principal point.
  const double du = std::max(K.cx + 0.5, K.width - 0.5 - K.cx) / K.fx;
  const double dv = std::max(K.cy + 0.5, K.height - 0.5 - K.cy) / K.fy;
  return max_depth_m * std::sqrt(1.0 + du * du + dv * dv);
}

MapPagerConfig pager_config_for_sensor(double memory_budget_mib, double evict_distance_m,
                                       const CameraIntrinsics& intrinsics, double max_depth_m,
                                       double motion_margin_m) {
  MapPagerConfig c;
  c.memory_budget_mib = memory_budget_mib;
  c.load_radius_m = sensor_reach_m(intrinsics, max_depth_m) + motion_margin_m;
  c.evict_distance_m = std::max(evict_distance_m, c.load_radius_m + 0.25);
  return c;
}

size_t MapPager::chunk_bytes(const Chunk& chunk) {
  return chunk.points.memory_bytes() + kChunkOverheadBytes;
}

MapPager::MapPager(const MapPagerConfig& config, ScanStore* store) : config_(config), store_(store) {}

Status MapPager::validate(const MapPagerConfig& c) {
  if (!(c.memory_budget_mib > 0.0)) return invalid_argument("memory_budget_mib must be positive");
  if (!(c.low_watermark_fraction > 0.0 && c.low_watermark_fraction <= 1.0))
    return invalid_argument("low_watermark_fraction must be in (0, 1]");
  if (!(c.load_radius_m > 0.0)) return invalid_argument("load_radius_m must be positive");
  if (c.evict_distance_m < c.load_radius_m)
    return invalid_argument("evict_distance_m (" + std::to_string(c.evict_distance_m) +
                            ") must not be smaller than load_radius_m (" +
                            std::to_string(c.load_radius_m) + "): chunks would be loaded and "
                            "evicted again");
  return Status::ok();
}

Status MapPager::update(PointMap* map, const Eigen::Vector3f& camera_position_m) {
  Status load = load_near(map, camera_position_m);
  Status evict = evict_far(map, camera_position_m);
  stats_.evicted_chunks = evicted_.size();
  stats_.unloadable_chunks = unloadable_.size();
  const Status& first_error = !load ? load : evict;
  if (!first_error) {
    ++stats_.failures;
    stats_.last_error = first_error.to_string();
  } else {
    stats_.last_error.clear();
  }
  return first_error;
}

Status MapPager::load_near(PointMap* map, const Eigen::Vector3f& cam) {
  if (evicted_.empty()) return Status::ok();
  const float radius = static_cast<float>(config_.load_radius_m);
  const int reach = static_cast<int>(std::ceil(radius / map->chunk_size_m())) + 1;
  const size_t cube = static_cast<size_t>(2 * reach + 1) * (2 * reach + 1) * (2 * reach + 1);
  to_load_.clear();
  if (evicted_.size() < cube) {
    for (const ChunkKey& k : evicted_)
      if (distance_to_chunk_m(*map, k, cam) <= radius) to_load_.push_back(k);
  } else {
    const ChunkKey c = map->key_for(cam);
    ChunkKey k;
    for (k.x = c.x - reach; k.x <= c.x + reach; ++k.x)
      for (k.y = c.y - reach; k.y <= c.y + reach; ++k.y)
        for (k.z = c.z - reach; k.z <= c.z + reach; ++k.z)
          if (evicted_.count(k) && distance_to_chunk_m(*map, k, cam) <= radius) to_load_.push_back(k);
  }
  Status first_error;
  for (const ChunkKey& k : to_load_) {
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
      // Fusion created the chunk while it was evicted: keep both sets of points.
      loaded.points.append(resident->points);
      loaded.last_touched_frame = std::max(loaded.last_touched_frame, resident->last_touched_frame);
      loaded.dirty = true;
      ++stats_.load_collisions;
    }
    map->insert(k, std::move(loaded));
    ++stats_.total_loaded;
  }
  return first_error;
}

Status MapPager::evict_far(PointMap* map, const Eigen::Vector3f& cam) {
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
  const float min_distance = static_cast<float>(config_.evict_distance_m);
  map->for_each_chunk([&](const ChunkKey& k, const Chunk& c) {
    const float d = distance_to_chunk_m(*map, k, cam);
    if (d > min_distance) candidates_.push_back({k, c.last_touched_frame, d, chunk_bytes(c)});
  });
  // Least recently touched first; among equals, the farthest.
  std::sort(candidates_.begin(), candidates_.end(), [](const Candidate& a, const Candidate& b) {
    if (a.last_touched_frame != b.last_touched_frame) return a.last_touched_frame < b.last_touched_frame;
    return a.distance_m > b.distance_m;
  });
  const size_t target = static_cast<size_t>(static_cast<double>(budget) * config_.low_watermark_fraction);
  size_t n = 0, freed = 0;
  while (n < candidates_.size() && resident - freed > target) freed += candidates_[n++].bytes;
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
    if (keep_key) evicted_.insert(k);
    unloadable_.erase(k);
  }
  stats_.total_evicted += n;
  stats_.resident_chunks = map->chunk_count();
  stats_.resident_bytes = resident - freed;
  if (config_.release_memory_to_os) malloc_trim(0);
  return Status::ok();
}

}  // namespace depthfuse::store
