// Bounded memory for the fused map. Two calls per frame:
//  - prepare() before the frame is processed loads back every evicted chunk the frame can touch:
//    the chunks around its back-projected depth (at the predicted pose, dilated by a margin that
//    covers ICP's correction and the pipeline's own chunk margins), so fusion and registration see
//    exactly the map an unbounded run would;
//  - update() after it: when the resident chunks exceed the low watermark, the least recently seen
//    ones (Chunk::last_seen_frame) that the camera has not seen for a while and that are not
//    right next to it are written to the scan file and dropped, a little a frame
//    (max_evict_mib_per_call). While a background checkpoint is in flight, changed chunks that
//    cannot be staged without waiting for it stay for a later frame (checkpoint_snapshot()).
//    Over the budget, whatever it takes: when those are not enough, the recently seen ones go
//    too, down to the budget, then those that wait for the checkpoint; never the ones this frame
//    observed or loaded, nor those near the camera.
// Per-call cost follows the frame, not the map: prepare() visits a subsample of the frame's
// pixels and looks their chunk keys up in the evicted index; update() scans only resident chunks,
// whose number the budget bounds.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <unordered_map>
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
  double low_watermark_fraction = 0.85;   // above this fraction of the budget, evict
  // Above the low watermark and within the budget, at most this much a call: encoding and staging
  // chunks costs the frame's thread, and 20 MiB at once held a frame for 80 ms, long enough for
  // the daemon's queue to drop frames. Over the budget, whatever it takes.
  double max_evict_mib_per_call = 2.0;
  double evict_distance_m = 1.5;          // chunks nearer to the camera than this stay resident
  // Chunks touched (or loaded) this recently are evicted only when evicting the older ones does
  // not bring the map under the budget.
  int min_age_frames = 30;
  // prepare(): a chunk within this distance of a back-projected depth sample is loaded. Covers
  // the pipeline's chunk margins (0.1 m) and the pose change ICP makes from the prediction.
  double load_margin_m = 0.3;
  int load_subsample_px = 4;              // prepare() looks at every n-th pixel in u and v
  int retry_after_failure_calls = 30;     // after a failed write, skip eviction this many calls
  bool release_memory_to_os = true;       // malloc_trim after evicting, so RSS follows the budget
  // Loads take a staged copy over the committed one (the pager's own evictions). False: only
  // committed chunks, for a reader that replays the frame log of a file killed mid-scan (its
  // staged chunks belong to the frames it replays).
  bool read_staged = true;
};

struct PagerStats {
  size_t resident_chunks = 0;
  size_t resident_bytes = 0;              // after the last update: the chunks and other_bytes
  size_t other_bytes = 0;                 // besides the chunks (set_other_bytes)
  size_t evicted_chunks = 0;              // keys in the evicted index
  size_t unevictable_bytes = 0;           // over budget, but all seen by the last frame or near
  size_t unloadable_chunks = 0;           // evicted chunks that failed to load (damaged)
  uint64_t total_evicted = 0, total_written = 0, total_loaded = 0;
  uint64_t total_evicted_recent = 0;      // of total_evicted: seen within min_age_frames
  uint64_t load_collisions = 0;           // a loaded chunk met a new resident one (points merged)
  uint64_t failures = 0;
  std::string last_error;                 // empty after a successful call
};

class MapPager {
 public:
  // `store` must be a writable scan and outlive the pager.
  MapPager(const MapPagerConfig& config, ScanStore* store);

  static Status validate(const MapPagerConfig& config);

  // Before IncrementalReconstructor::process(frame): loads the evicted chunks the frame can touch.
  // `T_world_cam_guess`: the frame's pose hint, else the prediction, else the last pose.
  // `frame_id`: the id the frame will get (IncrementalReconstructor::next_frame_id()).
  Status prepare(PointMap* map, const Frame& frame, const Pose& T_world_cam_guess, uint32_t frame_id);

  // What else the map's budget holds besides its chunks (the pose graph's keyframes, the map's
  // deformation history: they grow with the scan's length): chunks are evicted to leave room.
  void set_other_bytes(size_t bytes) { other_bytes_ = bytes; }

  // After the frame was fused, with the camera position in the world frame.
  Status update(PointMap* map, const Eigen::Vector3f& camera_position_m, uint32_t frame_id);

  // Loads the evicted chunks within `radius_m` of a point (e.g. around the camera on resume, so
  // that the first frame's tracking has its map). Visits the cube of keys, or the evicted index
  // when that is smaller.
  Status load_around(PointMap* map, const Eigen::Vector3f& p_m, double radius_m, uint32_t frame_id);

  // Loads those of `keys` that are evicted (a checkpoint puts the points the map's deformation
  // holds for them in their chunks).
  Status load_chunks(PointMap* map, const std::vector<ChunkKey>& keys, uint32_t frame_id);

  // The evicted chunks stored in a pose graph version older than `version`, in key order: the end
  // of a scan loads them, brings them up to date (their surfaces merged) and puts them back.
  std::vector<ChunkKey> evicted_before(uint32_t version) const;
  // Writes these resident chunks (the changed ones) to the scan file and drops them from the map,
  // whatever the budget. A key not in the map is skipped.
  Status evict_chunks(PointMap* map, const std::vector<ChunkKey>& keys);

  // Resume: a chunk that is in the scan file but not in memory, its points in the pose graph's
  // `version` (ChunkInfo::version).
  void mark_evicted(const ChunkKey& key, uint32_t version = 0) { note_evicted(key, version); }
  // The oldest pose graph version among the evicted chunks (none: nothing evicted): the map's
  // deformation keeps the history they need to follow the graph once loaded back
  // (MapDeformation::set_oldest_stored_version).
  std::optional<uint32_t> oldest_evicted_version() const {
    if (evicted_versions_.empty()) return std::nullopt;
    return evicted_versions_.begin()->first;
  }
  // In the scan file and not in memory: evicted, or failed to load (damaged; kept in the file).
  bool is_evicted(const ChunkKey& key) const {
    return evicted_.count(key) != 0 || unloadable_.count(key) != 0;
  }
  const std::unordered_set<ChunkKey, ChunkKeyHash>& evicted() const { return evicted_; }
  void forget(const ChunkKey& key) {
    note_loaded(key);
    unloadable_.erase(key);
  }

  // A checkpoint written in the background holds the map as of an earlier frame F and promotes
  // the chunks staged up to F. The recorder says when its snapshot is taken and when it is done
  // (a synchronous checkpoint, which promotes every staged chunk, says both). While it is in
  // flight, a chunk staged before the snapshot is not staged again: the new copy would replace
  // the one the checkpoint is to promote. Other changed chunks are staged as usual, unless the
  // checkpoint's transaction holds the file (`file_held`): then they wait for a later frame
  // rather than hold the fusion thread. Over the budget, eviction stages whatever it must, chunks
  // of the snapshot last, and calls `wait_for_checkpoint` first when that includes one of them.
  void checkpoint_snapshot();
  void checkpoint_done(bool committed);
  void set_checkpoint_hooks(std::function<bool()> file_held, std::function<void()> wait_for_checkpoint) {
    file_held_ = std::move(file_held);
    wait_for_checkpoint_ = std::move(wait_for_checkpoint);
  }

  // Brings the chunk at a key of the map up to the pose graph's current version (the map's
  // deformation). A chunk loaded where fusion or the deformation made a new one while it was
  // evicted is brought up to date before the two are merged: their points are in two versions,
  // and a chunk holds one. Without it the two are merged as they are.
  void set_bring_up_to_date(std::function<void(PointMap*, const ChunkKey&)> fn) {
    bring_up_to_date_ = std::move(fn);
  }

  // Bytes a chunk holds in memory, as the budget counts them.
  static size_t chunk_bytes(const Chunk& chunk);

  const MapPagerConfig& config() const { return config_; }
  const PagerStats& stats() const { return stats_; }

 private:
  size_t other_bytes_ = 0;
  Status load(PointMap* map, const std::vector<ChunkKey>& keys, uint32_t frame_id);
  Status evict(PointMap* map, const Eigen::Vector3f& camera_position_m, uint32_t frame_id);
  // Stages the changed ones of `keys` in one transaction, then drops them all from the map;
  // *written: how many were staged.
  Status stage_and_drop(PointMap* map, const std::vector<ChunkKey>& keys, size_t* written);
  // Whether staging this chunk must wait for the checkpoint in flight: a changed chunk of its
  // snapshot, which the checkpoint is to promote, is staged again only after it is done.
  bool staging_waits(const ChunkKey& key, const Chunk& chunk) const {
    return chunk.dirty && promoting_.count(key) != 0;
  }
  Status finish_call(Status st);
  void note_evicted(const ChunkKey& key, uint32_t version);
  void note_loaded(const ChunkKey& key);  // no longer evicted

  MapPagerConfig config_;
  ScanStore* store_;
  std::unordered_set<ChunkKey, ChunkKeyHash> evicted_;
  // The evicted chunks' versions, and how many are at each.
  std::unordered_map<ChunkKey, uint32_t, ChunkKeyHash> evicted_version_;
  std::map<uint32_t, size_t> evicted_versions_;
  std::unordered_set<ChunkKey, ChunkKeyHash> unloadable_;  // load failed; not retried every frame
  std::unordered_map<ChunkKey, uint32_t, ChunkKeyHash> loaded_at_;  // frame a chunk was loaded at
  PagerStats stats_;
  int skip_eviction_calls_ = 0;
  // Keys staged since the last checkpoint that promoted them, and of those the ones the checkpoint
  // in flight is to promote (checkpoint_snapshot()).
  std::unordered_set<ChunkKey, ChunkKeyHash> staged_, promoting_;
  bool checkpoint_in_flight_ = false;
  std::function<bool()> file_held_;
  std::function<void()> wait_for_checkpoint_;
  std::function<void(PointMap*, const ChunkKey&)> bring_up_to_date_;
  struct Candidate {
    ChunkKey key;
    uint32_t last_used_frame;
    float distance_m;
    size_t bytes;
    bool recent;  // used within min_age_frames
    bool waits;   // staging it waits for the checkpoint in flight (a changed chunk of its snapshot)
  };
  std::vector<Candidate> candidates_;
  std::vector<ChunkKey> keys_, drop_keys_;
};

// Distance from a point to a chunk's cube (0 inside).
float distance_to_chunk_m(const PointMap& map, const ChunkKey& key, const Eigen::Vector3f& p_m);

}  // namespace depthfuse::store
