// The fused map: points grouped into cubic chunks by a spatial hash. A frame only ever touches the
// chunks its own measurements fall into, so per-frame cost does not grow with the map.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <tuple>
#include <unordered_map>
#include <vector>

#include "depthfuse/point_arrays.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse {

struct ChunkKey {
  int32_t x = 0, y = 0, z = 0;
  bool operator==(const ChunkKey& o) const { return x == o.x && y == o.y && z == o.z; }
  bool operator!=(const ChunkKey& o) const { return !(*this == o); }
  // x, then y, then z: the one order chunk keys are listed and sorted in.
  bool operator<(const ChunkKey& o) const { return std::tie(x, y, z) < std::tie(o.x, o.y, o.z); }
};

struct ChunkKeyHash {
  size_t operator()(const ChunkKey& k) const {
    // Teschner et al. 2003 spatial hash primes.
    return (static_cast<size_t>(static_cast<uint32_t>(k.x)) * 73856093u) ^
           (static_cast<size_t>(static_cast<uint32_t>(k.y)) * 19349663u) ^
           (static_cast<size_t>(static_cast<uint32_t>(k.z)) * 83492791u);
  }
};

// The chunk keys one pass over a frame has already handled, in a small direct-mapped table:
// neighbouring samples name the same few chunks over and over, and this keeps most repeats away
// from costlier work (a sort, a hash set's look-up). A collision only lets a repeat through.
class SeenChunkKeys {
 public:
  // Whether k is in the table; puts it there.
  bool seen(const ChunkKey& k) {
    const size_t slot = ChunkKeyHash()(k) % kSlots;
    if (used_[slot] && keys_[slot] == k) return true;
    keys_[slot] = k;
    used_[slot] = true;
    return false;
  }

 private:
  static constexpr size_t kSlots = 256;
  ChunkKey keys_[kSlots];
  bool used_[kSlots] = {};
};

// A chunk's points are copy-on-write: a background checkpoint shares the arrays of the chunks it
// writes instead of copying them, and the first change after that copies them (points_for_write()).
// So the snapshot costs next to nothing on the fusion thread, and memory outside the map's budget
// is only what fusion changes while the checkpoint is being encoded, not the whole changed map.
class Chunk {
 public:
  const PointArrays& points() const { return points_ ? *points_ : empty_points(); }
  // The arrays to change in place; copies them first while a checkpoint in flight still holds
  // them. Unshared it costs a reference count's read, but hot loops take it once per chunk.
  PointArrays& points_for_write();
  // Whether another holder (a checkpoint in flight) shares the arrays now.
  bool points_shared() const { return points_ && points_.use_count() > 1; }

  // The newest frame that changed it: observed it, added points to it, or moved them (the map's
  // deformation). Checkpoints and the map's watchers go by it.
  uint32_t last_touched_frame = 0;
  // The newest frame that observed it or added points to it: the pager's recency. A loop closure's
  // deformation moves chunks all over the map without the camera going near them.
  uint32_t last_seen_frame = 0;
  bool dirty = true;                // changed since it was last written to a checkpoint
  // The pose graph's version the points are expressed in (MapDeformation): older than the map's
  // version() means a loop closure has moved their keyframes since, and they have not followed yet.
  uint32_t version = 0;

 private:
  static const PointArrays& empty_points();
  std::shared_ptr<PointArrays> points_;  // null: no points yet
};

class PointMap {
 public:
  explicit PointMap(double chunk_size_m = 0.5);

  double chunk_size_m() const { return chunk_size_m_; }
  ChunkKey key_for(float x_m, float y_m, float z_m) const;
  ChunkKey key_for(const Eigen::Vector3f& p) const { return key_for(p.x(), p.y(), p.z()); }
  Eigen::Vector3f chunk_origin_m(const ChunkKey& key) const;

  // The key of p's chunk and, where p lies within margin_m of a face (or edge, or corner), the keys
  // of the chunks across it: every chunk a point within margin_m of p can be in. Appends to *out.
  void keys_near(const Eigen::Vector3f& p, float margin_m, std::vector<ChunkKey>* out) const;

  Chunk* find(const ChunkKey& key);
  const Chunk* find(const ChunkKey& key) const;
  // A chunk it creates is at version().
  Chunk& get_or_create(const ChunkKey& key);
  // Takes a chunk in (e.g. loaded from a checkpoint), replacing any chunk with that key. The chunk
  // keeps its own version.
  void insert(const ChunkKey& key, Chunk chunk);

  // The pose graph's version new points are fused in, and new chunks created at (MapDeformation
  // keeps it; 0 until the first loop closure).
  uint32_t version() const { return version_; }
  void set_version(uint32_t version) { version_ = version; }
  // Removes a chunk and hands it back (e.g. to be written out). Empty optional if absent.
  bool extract(const ChunkKey& key, Chunk* out);
  void clear();

  size_t chunk_count() const { return chunks_.size(); }
  size_t point_count() const;
  size_t memory_bytes() const;

  void for_each_chunk(const std::function<void(const ChunkKey&, Chunk&)>& fn);
  void for_each_chunk(const std::function<void(const ChunkKey&, const Chunk&)>& fn) const;
  std::vector<ChunkKey> keys() const;

  // Every point in one array set (export, evaluation). Chunk order is sorted by key, so the result
  // is deterministic.
  PointArrays gather() const;

  // Re-buckets arbitrary points into chunks (e.g. a cloud read from disk).
  void add_points(const PointArrays& points);

 private:
  double chunk_size_m_;
  float inv_chunk_size_;
  std::unordered_map<ChunkKey, Chunk, ChunkKeyHash> chunks_;
  uint32_t version_ = 0;
};

}  // namespace depthfuse
