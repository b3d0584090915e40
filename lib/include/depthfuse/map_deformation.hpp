// How the fused map follows the pose graph. When a loop closure moves the keyframes' poses, every
// point moves with the keyframe it was fused from (PointState::last_frame names its frame, and the
// frame its keyframe segment), and the surfaces that then lie on each other (a wall seen on the
// first lap and, drifted, on the second) are fused into one with the paper's merge rule. Chunks
// follow lazily and a bounded number at a time (IncrementalReconstructor: those a frame sees before
// it is registered, then a sweep nearest to the camera first within a per-frame budget), so that
// the cost per frame stays independent of the map's size.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <unordered_map>
#include <vector>

#include "depthfuse/measurement.hpp"
#include "depthfuse/point_map.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse {

// What the deformation has done since it was made or cleared.
struct DeformationStats {
  uint64_t chunks_updated = 0;  // brought from an older version to the current one
  uint64_t points_updated = 0;  // brought up to date (moved unless their keyframe stayed)
  uint64_t points_crossed = 0;  // ... into another chunk
  uint64_t points_pending = 0;  // ... which was not up to date: held in its pending buffer
  uint64_t points_merged = 0;   // merged into a point of another visit (and so removed)
  // In a chunk older than the history kept (forget_versions_before()): left where they were.
  uint64_t points_unmovable = 0;
};

// The segment table and the pose history as plain data, for the scan file (history(), restore()).
struct DeformationHistory {
  // Keyframe k covers the frames from keyframe_first_frame[k] up to the next one's (the last: on).
  std::vector<uint32_t> keyframe_first_frame;
  uint32_t oldest_version = 0;  // the first version kept
  // Per version from oldest_version to the current one (the last entry): the poses of the
  // keyframes that existed then, 0, 1, 2 ..., in that version's world frame.
  std::vector<std::vector<Pose>> T_world_kf;
  // Per version as above: how far the correction that made it moved a point at most (0 for
  // version 0), m (MapDeformation::reach_m()).
  std::vector<double> max_motion_m;
  // The merge passes left for the sweep, in the order it runs them: chunks whose points followed a
  // correction (or took points in) but whose surfaces are not merged yet. A checkpoint taken then
  // keeps them, so that a resumed scan still merges those surfaces.
  struct QueuedMerge {
    ChunkKey key;
    uint32_t first_point = 0;   // the points from here on against all of the chunk's
    uint32_t from_version = 0;  // the corrections since this version
  };
  std::vector<QueuedMerge> merges;
};

// Points a correction moved into a chunk that had not followed it yet (stale, or stored out of
// memory), in the version they were moved to: they join the chunk when it is brought up to date.
// The scan file keeps them (MapDeformation::pending(), restore_pending()).
struct PendingPoints {
  ChunkKey key;
  uint32_t version = 0;
  PointArrays points;
};

class MapDeformation {
 public:
  // point_range_m: how far from its keyframe's camera a point lies at most (the sensor's range and
  // the way the camera goes within a keyframe segment), which bounds how far a correction that
  // turns a keyframe moves its points.
  explicit MapDeformation(double point_range_m = 5.0);
  ~MapDeformation();
  MapDeformation(MapDeformation&&) noexcept;
  MapDeformation& operator=(MapDeformation&&) noexcept;

  // Frames from `first_frame_id` on (until the next keyframe) belong to keyframe `keyframe` (ids
  // 0, 1, 2 ... in order), which sits at T_world_kf in the current version's frame. An error names
  // a keyframe out of order, a first frame not after the previous keyframe's, or a pose that is
  // not finite or not rigid; nothing changes then.
  Status keyframe_added(uint32_t keyframe, uint32_t first_frame_id, const Pose& T_world_kf);
  // The pose graph's new poses of keyframes 0..T_world_kf.size()-1: a new version, which it
  // returns. Keyframes added since the graph was snapshotted (index >= size) move rigidly with the
  // last one given. An error (more poses than keyframes, none, or a pose that is not finite or not
  // rigid) changes nothing.
  Result<uint32_t> correct(const std::vector<Pose>& T_world_kf);
  uint32_t version() const { return version_; }  // 0 until the first correction
  // The frame being processed: a chunk moved or merged counts as touched by it
  // (Chunk::last_touched_frame), so that the map's watchers (the operator's map preview) send it
  // again.
  void set_current_frame(uint32_t frame_id) { current_frame_ = frame_id; }
  size_t keyframe_count() const { return first_frame_.size(); }
  // The keyframe segment of a frame (frames before the first keyframe: 0).
  uint32_t keyframe_of(uint32_t frame_id) const;
  // Where a point fused by `frame_id` into a chunk at version `from` goes in the current version:
  // T_world_kf(now) * T_world_kf(at from)^-1 of its keyframe (identity when from == version(),
  // without keyframes, or from a version older than the history kept).
  Pose motion(uint32_t frame_id, uint32_t from_version) const;
  // How far a point of the oldest version kept moves at most to reach the current one (the sum of
  // the corrections' bounds since), m; 0 at version 0.
  double reach_m() const;

  // Brings the chunks with these keys up to date (those absent or current are skipped), then runs
  // the merge pass over them (lib/src/chunk_merge.hpp: pairs from two keyframes that the
  // correction moved apart). A point of a stale chunk moves by motion(): position, normal and
  // information (R L R^T). One that then falls in another chunk goes there if that chunk is up to
  // date or new, otherwise (stale, or stored out of memory: set_stored_elsewhere()) into that
  // chunk's pending buffer, applied when it is updated: no point moves twice. A chunk updated, or
  // one that took points in, is dirty. Returns the points brought up to date (pending ones
  // included).
  size_t update(PointMap* map, const std::vector<ChunkKey>& keys);
  // Before a frame is registered at T_world_cam: the chunks it sees from there (frame_chunk_keys(),
  // sampled as fusion samples them) and those holding points within reach_m() of it, which may
  // move into view, and within fusion's margin. Their points move now; their merge passes wait
  // for the sweep (they cost several times the move). Nothing at version 0.
  void update_visible(PointMap* map, const MeasurementImage& m, const Pose& T_world_cam) {
    if (version_ != 0) update_visible_now(map, m, T_world_cam);
  }
  // Before the frame is fused at the pose registration gave it: update_visible() again, unless the
  // chunks it covered still hold all the frame can see (the pose moved less than the chunks around
  // the view allow for; a relocalisation moves it far). Fusion must touch no chunk that has not
  // followed the last correction: its new points there would be moved a second time.
  void update_visible_if_moved(PointMap* map, const MeasurementImage& m, const Pose& T_world_cam) {
    if (version_ != 0) update_visible_if_moved_now(map, m, T_world_cam);
  }
  // After a frame: the merge passes update_visible() left, then other stale chunks, nearest to
  // camera_m first (listed once per correction), whole chunks until about max_points points were
  // merged or brought up to date. Once all are done, the history no chunk needs any more is
  // dropped. Returns the points gone over. Nothing at version 0.
  size_t sweep(PointMap* map, const Eigen::Vector3d& camera_m, size_t max_points) {
    return version_ == 0 ? 0 : sweep_now(map, camera_m, max_points);
  }
  // Points read from a chunk stored at `from_version` (an export streaming the scan file): moved
  // to the current version where they lie, none sent to another chunk and none merged. Returns the
  // points moved (0 when the chunk is current or older than the history kept).
  size_t move_in_place(PointArrays* points, uint32_t from_version);
  // Whether the sweep has chunks left to bring up to date since the last correction.
  bool sweeping() const { return version_ != 0 && (sweep_version_ != version_ || !sweep_done_); }
  // Every resident chunk (end of scan, export): the whole map in the current version, pending
  // buffers applied (except those of chunks not in memory), the history no chunk needs dropped.
  // Returns the points brought up to date.
  size_t bring_all_up_to_date(PointMap* map);

  // The history kept: versions from oldest_version() to version(). A chunk older than it cannot be
  // moved (its points stay where they are, counted in stats().points_unmovable).
  uint32_t oldest_version() const { return oldest_version_; }
  // The oldest version anything still needs: the map's chunks, the pending buffers, the merge
  // passes queued, and the chunks stored out of memory (set_oldest_stored_version()).
  uint32_t oldest_version_needed(const PointMap& map) const;
  // The oldest version among chunks stored out of memory (evicted to the scan file), which keeps
  // the history they need; none: nothing stored.
  void set_oldest_stored_version(std::optional<uint32_t> version) { oldest_stored_ = version; }
  // Which chunks absent from the map are in the scan file (evicted by the pager): points moved
  // there wait in the chunk's pending buffer until it is loaded and updated, rather than start a
  // new chunk at its key that the pager would have to load the stored one into at once. None set:
  // every absent chunk is new.
  void set_stored_elsewhere(std::function<bool(const ChunkKey&)> is_stored) {
    stored_elsewhere_ = std::move(is_stored);
  }
  // The chunks with points pending, in key order.
  std::vector<ChunkKey> pending_keys() const;
  // A copy of the points pending, by key then version (a checkpoint stores them as they are, so
  // that it need not bring their chunks up to date first).
  std::vector<PendingPoints> pending() const;
  // After restore(): the points pending as a checkpoint stored them. An error (a version outside
  // the history kept, the same key and version twice) changes nothing.
  Status restore_pending(std::vector<PendingPoints> pending);
  // Drops the poses of versions before `version` (at most the current one). Returns how many.
  size_t forget_versions_before(uint32_t version);

  // Plain data to store and restore (the scan file): the segment table and the history.
  DeformationHistory history() const;
  // Replaces everything by `h` (pending buffers and the sweep emptied). An error (keyframes out
  // of order, versions whose pose lists shrink or do not match max_motion_m, a pose that is not
  // rigid) changes nothing.
  Status restore(const DeformationHistory& h);
  void clear();

  size_t pending_points() const;
  // The pose history, the segment table, the pending points, the merges queued and the buffers
  // kept (the merge pass's grow to the largest chunk).
  size_t memory_bytes() const;
  const DeformationStats& stats() const { return stats_; }

 private:
  // A pose stored compactly: unit quaternion (w, x, y, z) and translation.
  struct StoredPose {
    double q[4];
    double t[3];
  };
  static StoredPose store(const Pose& T);
  static Pose load(const StoredPose& s);
  // Points moved into a chunk that was not up to date, in the version they were moved to.
  struct PendingGroup {
    uint32_t version = 0;
    PointArrays points;
  };
  // The poses of version v (oldest_version_ <= v <= version_).
  const std::vector<StoredPose>& poses_at(uint32_t v) const { return poses_[v - oldest_version_]; }
  // The motions from version `from` to now of every keyframe, in float (Scratch).
  void prepare_motions(uint32_t from);
  // Moves points [begin, end) of `a` from version `from` (prepare_motions() done).
  void move_points(PointArrays* a, size_t begin, size_t end);
  // Moves a stale chunk's points and its pending ones, sends those that left to their chunks.
  size_t move_chunk(PointMap* map, const ChunkKey& key, Chunk* chunk);
  // Point i of `from` (its chunk, `from_chunk`) now lies in chunk `key`: appended there or to its
  // pending buffer.
  void send(PointMap* map, const ChunkKey& key, const PointArrays& from, size_t i,
            const Chunk& from_chunk);
  // Whether the keyframes of a's points (Scratch::segment) moved the chunk at origin_m (edge
  // size_m) alike, to within kRigidM, since the version prepare_motions() was given.
  bool moved_rigidly(const PointArrays& a, const Eigen::Vector3f& origin_m, float size_m);
  // A merge pass to run: chunk `key` from its point `first` on, for the corrections since `from`.
  struct MergeJob {
    ChunkKey key;
    size_t first;
    uint32_t from;
  };
  // The merge passes the chunks updated_ and touched_ need: now, or queued for the sweep.
  void merge_updated(PointMap* map, bool defer);
  // Returns the points the pass went over.
  size_t run_merge(PointMap* map, const MergeJob& job);
  // Queued merges, oldest first, until they went over max_points points; returns how many.
  size_t run_queued_merges(PointMap* map, size_t max_points);
  // update() over keys[0, count), stopping once *updated reaches max_points; returns the index of
  // the first key not done.
  size_t update_range(PointMap* map, const ChunkKey* keys, size_t count, size_t max_points,
                      bool defer_merges, size_t* updated);
  void update_visible_now(PointMap* map, const MeasurementImage& m, const Pose& T_world_cam);
  void update_visible_if_moved_now(PointMap* map, const MeasurementImage& m,
                                   const Pose& T_world_cam);
  size_t sweep_now(PointMap* map, const Eigen::Vector3d& camera_m, size_t max_points);
  void drop_unneeded_history(const PointMap& map);
  // The bound on how far the correction from `before` to `after` moves a point.
  double max_motion(const std::vector<StoredPose>& before,
                    const std::vector<StoredPose>& after) const;

  double point_range_m_;
  uint32_t current_frame_ = 0;
  void touch(Chunk* chunk) const {
    chunk->dirty = true;
    if (current_frame_ > chunk->last_touched_frame) chunk->last_touched_frame = current_frame_;
  }
  // The segment table: keyframe k's first frame, searched by bisection (4 bytes a keyframe, however
  // long the scan; a chunk's points come in runs of one segment, so the last one found is tried
  // first).
  std::vector<uint32_t> first_frame_;
  // The history: poses_[v - oldest_version_] holds version v's keyframe poses, max_motion_m_ the
  // bound of the correction that made it. Why a list of poses per version rather than per keyframe
  // a list of the versions it changed in: a pose graph's solution moves every keyframe but the
  // fixed one, so a per-keyframe list would hold as much and need a search per lookup; a version's
  // poses are one array, dropped from the front when no chunk is that old any more.
  uint32_t version_ = 0;
  uint32_t oldest_version_ = 0;
  std::vector<std::vector<StoredPose>> poses_;
  std::vector<double> max_motion_m_;
  std::optional<uint32_t> oldest_stored_;
  std::function<bool(const ChunkKey&)> stored_elsewhere_;

  std::unordered_map<ChunkKey, std::vector<PendingGroup>, ChunkKeyHash> pending_;

  // Buffers kept from call to call: the keyframes' motions, the merge pass's.
  struct Scratch;
  std::unique_ptr<Scratch> scratch_;
  std::vector<ChunkKey> keys_, near_;
  struct UpdatedChunk {
    ChunkKey key;
    uint32_t from;  // the version its points came from
  };
  std::vector<UpdatedChunk> updated_;
  std::vector<std::pair<ChunkKey, size_t>> touched_;  // chunk, its first point taken in

  // What update_visible() last covered: the chunks around the view from this pose, at this
  // version, with this much to spare for the pose moving, m.
  Pose covered_T_world_cam_ = Pose::Identity();
  uint32_t covered_version_ = ~0u;
  double covered_spare_m_ = 0;

  // Merges update_visible() left for the sweep: one per chunk, in the order they were queued.
  std::unordered_map<ChunkKey, MergeJob, ChunkKeyHash> merge_queue_;
  std::vector<ChunkKey> merge_fifo_;  // from merge_fifo_head_ on; keys no longer queued skipped
  size_t merge_fifo_head_ = 0;

  // The sweep: the stale chunks when it started, nearest to the camera first; done once they and
  // the merge queue are.
  uint32_t sweep_version_ = 0;
  std::vector<ChunkKey> sweep_keys_;
  size_t sweep_next_ = 0;
  bool sweep_done_ = true;

  DeformationStats stats_;
};

}  // namespace depthfuse
