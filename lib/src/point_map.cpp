#include "depthfuse/point_map.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <tuple>

namespace depthfuse {

const PointArrays& Chunk::empty_points() {
  static const PointArrays empty;
  return empty;
}

PointArrays& Chunk::points_for_write() {
  if (!points_) {
    points_ = std::make_shared<PointArrays>();
  } else if (points_.use_count() > 1) {
    points_ = std::make_shared<PointArrays>(*points_);
  } else {
    // The last other holder (a checkpoint's encoder) let go on another thread: its release of the
    // count, read above, orders its reads of the arrays before the writes to come.
    std::atomic_thread_fence(std::memory_order_acquire);
  }
  return *points_;
}

PointMap::PointMap(double chunk_size_m)
    : chunk_size_m_(chunk_size_m), inv_chunk_size_(static_cast<float>(1.0 / chunk_size_m)) {}

ChunkKey PointMap::key_for(float x_m, float y_m, float z_m) const {
  return {static_cast<int32_t>(std::floor(x_m * inv_chunk_size_)),
          static_cast<int32_t>(std::floor(y_m * inv_chunk_size_)),
          static_cast<int32_t>(std::floor(z_m * inv_chunk_size_))};
}

Eigen::Vector3f PointMap::chunk_origin_m(const ChunkKey& key) const {
  const float s = static_cast<float>(chunk_size_m_);
  return {key.x * s, key.y * s, key.z * s};
}

void PointMap::keys_near(const Eigen::Vector3f& p, float margin_m, std::vector<ChunkKey>* out) const {
  const ChunkKey k = key_for(p);
  const Eigen::Vector3f o = chunk_origin_m(k);
  const float s = static_cast<float>(chunk_size_m_);
  int lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    const float f = p[a] - o[a];
    lo[a] = f < margin_m ? -1 : 0;
    hi[a] = f > s - margin_m ? 1 : 0;
  }
  for (int dx = lo[0]; dx <= hi[0]; ++dx)
    for (int dy = lo[1]; dy <= hi[1]; ++dy)
      for (int dz = lo[2]; dz <= hi[2]; ++dz) out->push_back({k.x + dx, k.y + dy, k.z + dz});
}

Chunk* PointMap::find(const ChunkKey& key) {
  auto it = chunks_.find(key);
  return it == chunks_.end() ? nullptr : &it->second;
}

const Chunk* PointMap::find(const ChunkKey& key) const {
  auto it = chunks_.find(key);
  return it == chunks_.end() ? nullptr : &it->second;
}

Chunk& PointMap::get_or_create(const ChunkKey& key) {
  const auto [it, created] = chunks_.try_emplace(key);
  if (created) it->second.version = version_;
  return it->second;
}

void PointMap::insert(const ChunkKey& key, Chunk chunk) { chunks_[key] = std::move(chunk); }

bool PointMap::extract(const ChunkKey& key, Chunk* out) {
  auto it = chunks_.find(key);
  if (it == chunks_.end()) return false;
  if (out) *out = std::move(it->second);
  chunks_.erase(it);
  return true;
}

void PointMap::clear() { chunks_.clear(); }

size_t PointMap::point_count() const {
  size_t n = 0;
  for (const auto& kv : chunks_) n += kv.second.points().size();
  return n;
}

size_t PointMap::memory_bytes() const {
  size_t bytes = chunks_.bucket_count() * sizeof(void*);
  for (const auto& kv : chunks_) bytes += sizeof(kv) + kv.second.points().memory_bytes();
  return bytes;
}

void PointMap::for_each_chunk(const std::function<void(const ChunkKey&, Chunk&)>& fn) {
  for (auto& kv : chunks_) fn(kv.first, kv.second);
}

void PointMap::for_each_chunk(const std::function<void(const ChunkKey&, const Chunk&)>& fn) const {
  for (const auto& kv : chunks_) fn(kv.first, kv.second);
}

std::vector<ChunkKey> PointMap::keys() const {
  std::vector<ChunkKey> k;
  k.reserve(chunks_.size());
  for (const auto& kv : chunks_) k.push_back(kv.first);
  std::sort(k.begin(), k.end());
  return k;
}

PointArrays PointMap::gather() const {
  PointArrays all;
  all.reserve(point_count());
  for (const ChunkKey& k : keys()) all.append(chunks_.at(k).points());
  return all;
}

void PointMap::add_points(const PointArrays& points) {
  for (size_t i = 0; i < points.size(); ++i) {
    get_or_create(key_for(points.position_m[i])).points_for_write().push_back(points.position_m[i], points.state[i]);
  }
}

}  // namespace depthfuse
