// Bounded memory for the fused map: when the resident chunks exceed a budget, the least recently
// touched chunks far from the camera are written to the scan file and dropped; evicted chunks the
// camera comes back to are loaded again. Cost per call does not grow with the map: loading visits
// the cube of chunk keys within the load radius (or the evicted index, when that is smaller), and
// eviction scans only the resident chunks, whose number the budget bounds.
#pragma once

#include <cstdint>
#include <string>
#include <unordered_set>
#include <vector>

#include <Eigen/Core>

#include "depthfuse/point_map.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::store {

class ScanStore;

struct MapPagerConfig {
  double memory_budget_mib = 256.0;       // resident point data of the map
  double low_watermark_fraction = 0.85;   // evict down to this fraction of the budget
  double evict_distance_m = 7.0;          // chunks nearer to the camera than this stay resident
  // Evicted chunks nearer than this are loaded back: the sensor's reach (sensor_reach_m, not
  // just its max depth: the corner rays are longer) plus a margin for the motion until the next
  // call. Must not exceed evict_distance_m (or loads would thrash).
  double load_radius_m = 6.6;
  int retry_after_failure_calls = 30;     // after a failed write, skip eviction this many calls
  bool release_memory_to_os = true;       // malloc_trim after evicting, so RSS follows the budget
};

struct PagerStats {
  size_t resident_chunks = 0;
  size_t resident_bytes = 0;              // after the last update
  size_t evicted_chunks = 0;              // keys in the evicted index
  size_t unevictable_bytes = 0;           // over budget but within evict_distance_m
  uint64_t total_evicted = 0, total_written = 0, total_loaded = 0;
  uint64_t load_collisions = 0;           // a loaded chunk met a new resident one (points merged)
  uint64_t failures = 0;
  size_t unloadable_chunks = 0;           // evicted chunks that failed to load (damaged)
  std::string last_error;                 // empty after a successful update
};

class MapPager {
 public:
  // `store` must be a writable scan and outlive the pager.
  MapPager(const MapPagerConfig& config, ScanStore* store);

  static Status validate(const MapPagerConfig& config);

  // Once per frame, after fusion, with the camera position in the world frame.
  Status update(PointMap* map, const Eigen::Vector3f& camera_position_m);

  // Resume: a chunk that is in the scan file but not in memory.
  void mark_evicted(const ChunkKey& key) { evicted_.insert(key); }
  // In the scan file and not in memory: evicted, or failed to load (damaged; kept in the file).
  bool is_evicted(const ChunkKey& key) const {
    return evicted_.count(key) != 0 || unloadable_.count(key) != 0;
  }
  const std::unordered_set<ChunkKey, ChunkKeyHash>& evicted() const { return evicted_; }
  void forget(const ChunkKey& key) {
    evicted_.erase(key);
    unloadable_.erase(key);
  }

  // Bytes a chunk holds in memory, as the budget counts them.
  static size_t chunk_bytes(const Chunk& chunk);

  const MapPagerConfig& config() const { return config_; }
  const PagerStats& stats() const { return stats_; }

 private:
  Status load_near(PointMap* map, const Eigen::Vector3f& camera_position_m);
  Status evict_far(PointMap* map, const Eigen::Vector3f& camera_position_m);

  MapPagerConfig config_;
  ScanStore* store_;
  std::unordered_set<ChunkKey, ChunkKeyHash> evicted_;
  std::unordered_set<ChunkKey, ChunkKeyHash> unloadable_;  // load failed; not retried every frame
  PagerStats stats_;
  int skip_eviction_calls_ = 0;
  struct Candidate {
    ChunkKey key;
    uint32_t last_touched_frame;
    float distance_m;
    size_t bytes;
  };
  std::vector<Candidate> candidates_;
  std::vector<ChunkKey> to_load_;
};

// How far from the camera a measurement can lie: max_depth_m along the ray through the farthest
// image corner (Kinect V2 at 4.5 m: 6.1 m). Fusion and ICP touch only chunks within this reach
// (plus their small margins) of the camera.
double sensor_reach_m(const CameraIntrinsics& intrinsics, double max_depth_m);

// A pager configuration for a sensor: load radius = reach + motion margin, eviction beyond that
// (at least `evict_distance_m`).
MapPagerConfig pager_config_for_sensor(double memory_budget_mib, double evict_distance_m,
                                       const CameraIntrinsics& intrinsics, double max_depth_m,
                                       double motion_margin_m = 0.5);

// Distance from a point to a chunk's cube (0 inside).
float distance_to_chunk_m(const PointMap& map, const ChunkKey& key, const Eigen::Vector3f& p_m);

}  // namespace depthfuse::store
