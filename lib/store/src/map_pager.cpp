// The memory pager: owns the index of evicted chunks and moves chunks between the map and the scan
// file's staging table. Runs on the fusion daemon's worker thread, between frames (ScanRecorder).
#include "depthfuse/store/map_pager.hpp"

#include <malloc.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <tuple>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/store/scan_store.hpp"

DF_LOG_CATEGORY(Pager)

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

size_t MapPager::chunk_bytes(const Chunk& chunk) {
  return chunk.points().memory_bytes() + kChunkOverheadBytes;
}

MapPager::MapPager(const MapPagerConfig& config, ScanStore* store) : config_(config), store_(store) {}

Status MapPager::validate(const MapPagerConfig& c) {
  if (!(c.memory_budget_mib > 0.0)) return invalid_argument("memory_budget_mib must be positive");
  if (!(c.low_watermark_fraction > 0.0 && c.low_watermark_fraction <= 1.0))
    return invalid_argument("low_watermark_fraction must be in (0, 1]");
  if (!(c.evict_distance_m >= 0.0)) return invalid_argument("evict_distance_m must be >= 0");
  if (c.min_age_frames < 0) return invalid_argument("min_age_frames must be >= 0");
  if (!(c.max_evict_mib_per_call > 0.0)) return invalid_argument("max_evict_mib_per_call must be positive");
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
  // Per block of step x step pixels, the stretch of the block's ray from 0.9 of its nearest depth to
  // its farthest: the surface points of every pixel (not only a sampled one: a block across a depth
  // edge holds a near and a far surface) and the stretch in front of them (0.9 .. 1.0 of the
  // range) that visibility checks look at. Samples along it are at most `margin` apart, and the
  // radius grows by the block's lateral extent at that depth.
  const float inv_fx = 1.0f / fx;
  // Neighbouring samples name the same chunks: each is looked up in the evicted set once, nearly.
  SeenChunkKeys checked;
  for (int v0 = 0; v0 < d.height; v0 += step) {
    for (int u0 = 0; u0 < d.width; u0 += step) {
      float zmin = std::numeric_limits<float>::infinity(), zmax = 0.0f;
      const int v1 = std::min(v0 + step, d.height), u1 = std::min(u0 + step, d.width);
      for (int v = v0; v < v1; ++v) {
        const float* row = d.depth_m.data() + static_cast<size_t>(v) * d.width;
        for (int u = u0; u < u1; ++u) {
          const float z = row[u];
          if (!(z > 0.0f) || !std::isfinite(z)) continue;
          zmin = std::min(zmin, z);
          zmax = std::max(zmax, z);
        }
      }
      if (!(zmax > 0.0f)) continue;
      const float uc = 0.5f * static_cast<float>(u0 + u1 - 1), vc = 0.5f * static_cast<float>(v0 + v1 - 1);
      const Eigen::Vector3f ray((uc - cx) / fx, (vc - cy) / fy, 1.0f);  // at z = 1
      const float radius = margin + 0.75f * static_cast<float>(step) * zmax * inv_fx;
      for (float z = 0.9f * zmin;; z += margin) {
        const float zs = std::min(z, zmax);
        // Only the evicted keys are kept, as they come: the samples name a hundred thousand keys
        // or more a frame, mostly resident ones, and sorting them all cost more than the rest of
        // the frame. A key checked before in this frame is dropped: kept then if evicted.
        const size_t first = keys_.size();
        map->keys_near(R * (zs * ray) + t, radius, &keys_);
        keys_.erase(std::remove_if(keys_.begin() + static_cast<std::ptrdiff_t>(first), keys_.end(),
                                   [&](const ChunkKey& k) {
                                     return checked.seen(k) || !evicted_.count(k);
                                   }),
                    keys_.end());
        if (zs >= zmax || !(margin > 0.0f)) break;
      }
    }
  }
  std::sort(keys_.begin(), keys_.end());
  keys_.erase(std::unique(keys_.begin(), keys_.end()), keys_.end());
  if (!keys_.empty())
    DF_LOG(Pager, Debug) << "frame " << frame_id << ": loading " << keys_.size()
                          << " chunks the frame can touch";
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
  std::sort(keys_.begin(), keys_.end());
  return finish_call(load(map, keys_, frame_id));
}

Status MapPager::load_chunks(PointMap* map, const std::vector<ChunkKey>& keys, uint32_t frame_id) {
  keys_.clear();
  for (const ChunkKey& k : keys)
    if (evicted_.count(k)) keys_.push_back(k);
  if (keys_.empty()) return Status::ok();
  return finish_call(load(map, keys_, frame_id));
}

Status MapPager::load(PointMap* map, const std::vector<ChunkKey>& keys, uint32_t frame_id) {
  Status first_error;
  for (const ChunkKey& k : keys) {
    auto stored = store_->read_chunk(k, config_.read_staged);
    note_loaded(k);
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
    if (Chunk* resident = map->find(k);
        resident && bring_up_to_date_ && resident->version != loaded.version) {
      // The stored points follow the corrections made since they were evicted, in the map under
      // their key, then the resident ones join them.
      Chunk newer;
      map->extract(k, &newer);
      map->insert(k, std::move(loaded));
      bring_up_to_date_(map, k);
      Chunk& merged = map->get_or_create(k);
      merged.points_for_write().append(newer.points());
      merged.last_touched_frame = std::max(merged.last_touched_frame, newer.last_touched_frame);
      merged.last_seen_frame = std::max(merged.last_seen_frame, newer.last_seen_frame);
      merged.dirty = true;
      ++stats_.load_collisions;
      loaded_at_[k] = frame_id;
      ++stats_.total_loaded;
      continue;
    }
    if (Chunk* resident = map->find(k)) {
      // Fusion created the chunk while it was evicted (prepare() was skipped or the pose jumped):
      // keep both sets of points.
      loaded.points_for_write().append(resident->points());
      loaded.last_touched_frame = std::max(loaded.last_touched_frame, resident->last_touched_frame);
      loaded.last_seen_frame = std::max(loaded.last_seen_frame, resident->last_seen_frame);
      loaded.dirty = true;
      ++stats_.load_collisions;
    }
    map->insert(k, std::move(loaded));
    loaded_at_[k] = frame_id;
    ++stats_.total_loaded;
  }
  return first_error;
}

void MapPager::checkpoint_snapshot() {
  promoting_ = staged_;
  checkpoint_in_flight_ = true;
}

void MapPager::checkpoint_done(bool committed) {
  // Committed, it promoted every chunk staged before its snapshot; failed, they wait for the next.
  if (committed)
    for (const ChunkKey& k : promoting_) staged_.erase(k);
  promoting_.clear();
  checkpoint_in_flight_ = false;
}

void MapPager::note_evicted(const ChunkKey& key, uint32_t version) {
  note_loaded(key);  // evicted again: its version is the new one
  evicted_.insert(key);
  evicted_version_[key] = version;
  ++evicted_versions_[version];
}

void MapPager::note_loaded(const ChunkKey& key) {
  evicted_.erase(key);
  const auto it = evicted_version_.find(key);
  if (it == evicted_version_.end()) return;
  const auto count = evicted_versions_.find(it->second);
  if (--count->second == 0) evicted_versions_.erase(count);
  evicted_version_.erase(it);
}

Status MapPager::update(PointMap* map, const Eigen::Vector3f& camera_position_m, uint32_t frame_id) {
  // A chunk fusion created at an evicted key that prepare() did not load (the refined pose moved
  // farther than load_margin_m from the guess, say): its stored points come back now and join the
  // new ones, before a checkpoint or an eviction could write the new chunk over the stored one.
  if (!evicted_.empty()) {
    keys_.clear();
    map->for_each_chunk([&](const ChunkKey& k, const Chunk&) {
      if (evicted_.count(k)) keys_.push_back(k);
    });
    if (!keys_.empty()) {
      DF_LOG(Pager, Debug) << "frame " << frame_id << ": " << keys_.size()
                            << " chunks made at evicted keys are joined with their stored points";
      std::sort(keys_.begin(), keys_.end());
      if (Status st = load(map, keys_, frame_id); !st) return finish_call(st);
    }
  }
  return finish_call(evict(map, camera_position_m, frame_id));
}

Status MapPager::evict(PointMap* map, const Eigen::Vector3f& cam, uint32_t frame_id) {
  const size_t budget = static_cast<size_t>(config_.memory_budget_mib * 1024.0 * 1024.0);
  size_t resident = other_bytes_;
  map->for_each_chunk([&](const ChunkKey&, const Chunk& c) { resident += chunk_bytes(c); });
  stats_.other_bytes = other_bytes_;
  stats_.resident_chunks = map->chunk_count();
  stats_.resident_bytes = resident;
  stats_.unevictable_bytes = 0;
  const size_t target = static_cast<size_t>(static_cast<double>(budget) * config_.low_watermark_fraction);
  if (resident <= target) return Status::ok();
  const bool over_budget = resident > budget;
  if (skip_eviction_calls_ > 0) {
    --skip_eviction_calls_;
    return Status::ok();
  }

  candidates_.clear();
  const float keep_distance = static_cast<float>(config_.evict_distance_m);
  const uint32_t min_age = static_cast<uint32_t>(config_.min_age_frames);
  const bool file_held = checkpoint_in_flight_ && file_held_ && file_held_();
  map->for_each_chunk([&](const ChunkKey& k, const Chunk& c) {
    uint32_t used = c.last_seen_frame;
    if (auto it = loaded_at_.find(k); it != loaded_at_.end()) used = std::max(used, it->second);
    if (used >= frame_id) return;  // observed by (or loaded for) this very frame
    const float d = distance_to_chunk_m(*map, k, cam);
    if (d <= keep_distance) return;
    // Within the budget, a changed chunk whose staging would wait for the checkpoint in flight
    // stays for a later frame.
    const bool waits = staging_waits(k, c);
    if (!over_budget && c.dirty && (file_held || waits)) return;
    candidates_.push_back({k, used, d, chunk_bytes(c), used + min_age >= frame_id, waits});
  });
  // Least recently used first; among equals, the farthest. The recently seen come after, and last
  // those that would wait for the checkpoint in flight: over the budget, a chunk loaded back soon
  // after costs a read, the wait holds the frame for the checkpoint's encoding and transaction.
  std::sort(candidates_.begin(), candidates_.end(), [](const Candidate& a, const Candidate& b) {
    if (a.waits != b.waits) return b.waits;
    if (a.last_used_frame != b.last_used_frame) return a.last_used_frame < b.last_used_frame;
    return a.distance_m > b.distance_m;
  });
  // Chunks not seen for min_age_frames go first, towards the low watermark, at most
  // max_evict_mib_per_call beyond what brings the map within the budget. Only when they do not
  // bring the map under the budget itself do recently seen ones go too (just down to the budget,
  // as the next frames may load them back): the views of the last min_age_frames frames can hold
  // more than the budget (a walk back into mapped rooms loads their full chunks), and the budget
  // must hold anyway. What stays is this frame's chunks and those near the camera.
  const size_t step = static_cast<size_t>(config_.max_evict_mib_per_call * 1024.0 * 1024.0);
  const size_t to_free =
      std::min(resident - target, (over_budget ? resident - budget : 0) + step);
  size_t n = 0, freed = 0, recent = 0;
  while (n < candidates_.size() && !candidates_[n].recent && !candidates_[n].waits && freed < to_free)
    freed += candidates_[n++].bytes;
  while (n < candidates_.size() && resident - freed > budget) {
    freed += candidates_[n++].bytes;
    ++recent;
  }
  if (resident - freed > budget) stats_.unevictable_bytes = resident - freed - budget;
  if (n == 0) return Status::ok();

  bool wait = false;
  drop_keys_.clear();
  for (size_t i = 0; i < n; ++i) {
    drop_keys_.push_back(candidates_[i].key);
    wait |= candidates_[i].waits;
  }
  // Once the checkpoint is done its promotion is too: the chunks of its snapshot may be staged.
  const int64_t t0_ns = steady_ns();
  if (wait && wait_for_checkpoint_) wait_for_checkpoint_();
  const int64_t t1_ns = steady_ns();
  size_t written = 0;
  if (Status st = stage_and_drop(map, drop_keys_, &written); !st)
    return st.with_context("evicting " + std::to_string(n) + " chunks (they stay in memory)");
  const int64_t t2_ns = steady_ns();
  stats_.total_evicted += n;
  stats_.total_evicted_recent += recent;
  stats_.resident_chunks = map->chunk_count();
  stats_.resident_bytes = resident - freed;
  DF_LOG(Pager, Debug) << "frame " << frame_id << ": evicted " << n << " chunks (" << recent
                        << " seen recently, " << written << " written), "
                        << (resident >> 20) << " -> " << ((resident - freed) >> 20) << " MiB; "
                        << "waited " << (t1_ns - t0_ns) / 1000000 << " ms for the checkpoint, "
                        << "staged in " << (t2_ns - t1_ns) / 1000000 << " ms";
  if (config_.release_memory_to_os) malloc_trim(0);
  return Status::ok();
}

Status MapPager::stage_and_drop(PointMap* map, const std::vector<ChunkKey>& keys, size_t* written) {
  // Changed chunks go to the scan file first, all in one transaction; only then are they dropped.
  std::vector<std::pair<ChunkKey, const Chunk*>> writes;
  for (const ChunkKey& k : keys)
    if (const Chunk* c = map->find(k); c && c->dirty) writes.emplace_back(k, c);
  if (Status st = store_->stage_chunks(writes); !st) {
    skip_eviction_calls_ = config_.retry_after_failure_calls;
    return st;
  }
  stats_.total_written += writes.size();
  *written = writes.size();
  for (const auto& w : writes) {
    staged_.insert(w.first);
    promoting_.erase(w.first);  // staged again after that checkpoint: for the next one to promote
  }
  for (const ChunkKey& k : keys) {
    const Chunk* c = map->find(k);
    if (!c) continue;
    // A clean, empty chunk has nothing in the file and nothing to come back to.
    const bool keep_key = c->dirty || !c->points().empty();
    const uint32_t c_version = c->version;
    map->extract(k, nullptr);
    loaded_at_.erase(k);
    unloadable_.erase(k);
    if (keep_key) note_evicted(k, c_version);
  }
  return Status::ok();
}

std::vector<ChunkKey> MapPager::evicted_before(uint32_t version) const {
  std::vector<ChunkKey> keys;
  for (const auto& [key, v] : evicted_version_)
    if (v < version) keys.push_back(key);
  std::sort(keys.begin(), keys.end());
  return keys;
}

Status MapPager::evict_chunks(PointMap* map, const std::vector<ChunkKey>& keys) {
  const bool wait = std::any_of(keys.begin(), keys.end(), [&](const ChunkKey& k) {
    const Chunk* c = map->find(k);
    return c && staging_waits(k, *c);
  });
  if (wait && wait_for_checkpoint_) wait_for_checkpoint_();
  size_t written = 0;
  Status st = stage_and_drop(map, keys, &written);
  if (st) {
    stats_.total_evicted += keys.size();
    stats_.resident_chunks = map->chunk_count();
  }
  return finish_call(st.with_context("evicting " + std::to_string(keys.size()) +
                                     " chunks (they stay in memory)"));
}

}  // namespace depthfuse::store
