// What the fusion daemon needs from the store, in one object: a new or resumed scan file, the pose
// of every fused frame, a keyframe every n frames, bounded memory through the MapPager, and
// checkpoints (periodic ones written by a thread of its own, on command, on SIGTERM, final). All
// calls come from one thread (the fusion daemon's worker), which owns the recorder's connection to
// the file; the recorder's two threads (background checkpoints, the frame redo log) each write on
// a connection of their own. Errors are returned and also kept in status() for the heartbeat; a
// failed checkpoint leaves the previous one intact and everything it would have written stays
// pending for the next attempt.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "depthfuse/pipeline.hpp"
#include "depthfuse/point_map.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/store/map_pager.hpp"
#include "depthfuse/store/scan_store.hpp"

namespace depthfuse::store {

class CheckpointWriter;
struct CheckpointJob;
class FrameLogWriter;

// The frame redo log's thread: what it has done (RecorderStatus::frame_log).
struct FrameLogStats {
  uint64_t frames_logged = 0;            // committed to the file by this process
  uint32_t last_logged_frame = 0;        // newest committed record
  size_t frames_waiting = 0;             // pushed, not yet committed
  uint64_t encoded_bytes_waiting = 0;
  uint64_t commits = 0, failures = 0, frames_dropped = 0;
  double encode_seconds = 0, write_seconds = 0;  // the thread's wall time so far
  double cpu_seconds = 0;                // the thread's CPU time in them
  // How far behind the log is: the oldest frame not committed was pushed this long ago; the
  // most a committed frame waited.
  double lag_seconds = 0, max_lag_seconds = 0;
  // The fusion thread's waits for the log: its time in push() (waits over 1 ms), and how often it
  // waited because the log was a whole lag bound behind.
  double waited_seconds = 0;
  uint64_t lag_waits = 0;
  Status last_error;                     // the latest of `failures`, kept after later commits
};

struct RecorderConfig {
  bool bounded_memory = true;        // run the MapPager
  MapPagerConfig pager;
  int keyframe_every_n_frames = 10;  // 0 = no keyframes
  bool keyframe_color = true;        // store the registered colour image with the depth
  // zstd level of the chunks background checkpoints write: they rewrite every chunk in view about
  // every second, so speed counts for more than the last few percent of size.
  int background_compression_level = 1;
  StoreOptions store;
  // The frame redo log (docs/checkpoint-format.md): every recorded frame's pose, depth and colour,
  // encoded and committed by a thread of the recorder, so that a crash loses at most the frames
  // recorded in the last frame_log_interval_s (record_frame waits when the log is that far
  // behind), while full checkpoints (which rewrite every chunk changed since the last) come
  // seldom. 0 = no log: a crash loses what came after the last checkpoint.
  double frame_log_interval_s = 0.0;
  // Raw frames waiting for the log's thread (then record_frame waits), and the encoded frames'
  // size at which they are committed early. Small: both count in the daemon's per-frame budget,
  // and the thread encodes a frame as it comes. A few frames, not one: on two busy cores the
  // thread is not always scheduled within a frame period, and with one slot the fusion thread
  // waited for it.
  size_t frame_log_queue_frames = 3;
  size_t frame_log_commit_bytes = 1u << 20;
  // zstd levels of the log's depth and colour. A camera's colour loses little to a fast level (it
  // hardly compresses losslessly at any), and at level 1 its encoding cost more than the depth's.
  int frame_log_compression_level = 1;
  int frame_log_color_compression_level = -5;
  // What the frame log holds in memory at most, for frames of `pixels` pixels, bytes: the raw
  // frames waiting and the one being encoded (depth as float, colour RGB), the encoded frames
  // waiting and those in the transaction (each up to the commit size and one more record, at
  // most its 16-bit depth and RGB).
  static size_t frame_log_bytes(const RecorderConfig& config, size_t pixels);
};

// Frame counters the daemon keeps (queue drops happen before the recorder sees a frame; frames
// tracked only or lost never reach it). The recorder counts the fused frames itself.
struct FrameCounters {
  uint64_t received = 0;
  uint64_t dropped = 0;
  uint64_t tracked_only = 0;
  uint64_t lost = 0;
};

// The counters a scan file holds (its metadata), to go on from when it is resumed or folded.
inline FrameCounters frame_counters_of(const ScanMetadata& m) {
  return {m.frames_received, m.frames_dropped, m.frames_tracked_only, m.frames_lost};
}

struct RecorderStatus {
  std::string path;
  uint64_t frames_recorded = 0;
  uint64_t keyframes_written = 0;
  size_t pending_poses = 0;                  // recorded since the last checkpoint
  uint64_t checkpoints_written = 0;          // by this process
  std::optional<CheckpointRecord> last_checkpoint;
  double last_checkpoint_seconds = 0.0;      // how long the last checkpoint took, start to commit
  // The last background checkpoint: the caller's share (copying what changed), then the writer
  // thread's (encoding the chunks; the transaction and its fsync).
  double last_snapshot_seconds = 0.0;
  double last_encode_seconds = 0.0, last_write_seconds = 0.0;
  double total_encode_seconds = 0.0, total_write_seconds = 0.0;  // all background checkpoints
  size_t last_checkpoint_chunks = 0;         // chunks the last checkpoint wrote
  PagerStats pager;
  StatusCode last_error_code = StatusCode::kOk;
  std::string last_error;                    // the latest failure, cleared by the next success
  // The latest failed checkpoint, cleared only by a successful one (a full disk stays visible in
  // the heartbeat while frames keep being fused).
  std::string checkpoint_error;
  StatusCode checkpoint_error_code = StatusCode::kOk;
  uint64_t checkpoint_failures = 0;
  // The latest of checkpoint_failures, kept after later successes: whoever reports failures as
  // the count grows needs the newest one's error, and one call can collect a background
  // checkpoint's failure and then commit a checkpoint of its own.
  Status last_checkpoint_failure;
  FrameLogStats frame_log;                   // the frame redo log's thread (when it runs)
  // Frames fused after a correction that no checkpoint held yet, left out of the frame log
  // (ScanRecorder::record_frame).
  uint64_t frames_not_logged_after_correction = 0;
};

// Where a resumed scan continues.
struct ResumePoint {
  std::unique_ptr<PointMap> map;             // chunks near the last camera position (or all)
  uint32_t next_frame_id = 1;
  std::optional<Pose> last_T_world_cam;
  ScanMetadata metadata;
  std::optional<CheckpointRecord> checkpoint;
  OpenReport open_report;                    // what was discarded (work after the checkpoint)
  // The frame redo log's records after the checkpoint: ScanRecorder::replay_log() fuses them.
  FrameLogSummary frame_log;
  // The checkpoint's pose graph and map deformation (none: the scan has none). The map's chunks
  // carry their versions.
  std::optional<GraphCheckpoint> graph;
  // The points the checkpoint held pending for chunks that had not followed a correction
  // (MapDeformation::restore_pending() after the graph's deformation is restored).
  std::vector<PendingPoints> pending;
};

// A scan file's map follows its pose graph as the last checkpoint left it, before the frame log's
// records are replayed (they were fused in the graph's version): the deformation's history, the
// map's version and the points waiting for their chunks. An error names what does not fit (points
// pending without a graph, a version outside the history), `path` first.
Status restore_deformation(const std::optional<GraphCheckpoint>& graph,
                           std::vector<PendingPoints> pending, const std::string& path,
                           MapDeformation* deformation, PointMap* map);
// One map's pager and deformation: points a correction moves into a chunk the pager holds in the
// file wait for it (rather than start a chunk at its key), and a stored chunk loaded where fusion
// started one follows the corrections before the two are joined. Both must outlive the link.
void link_pager(MapPager* pager, MapDeformation* deformation);

// What ScanRecorder::restore_keyframes() did.
struct KeyframeRestoreReport {
  size_t stored = 0;                 // keyframes of the last checkpoint in the file (rows intact)
  size_t chosen = 0;                 // wanted by place from their poses: the only ones decoded
  size_t restored = 0;               // that became relocalisation keyframes
  std::vector<uint32_t> restored_frames;  // their frame ids, newest first
  size_t chunks_loaded = 0;          // evicted chunks brought back for their views
  std::vector<std::string> skipped;  // one per keyframe left out for damage, and why
  double seconds = 0.0;
};

class ScanRecorder {
 public:
  // A new scan file (fails if `path` exists). Stores the metadata and the configuration text.
  static Result<std::unique_ptr<ScanRecorder>> create(const std::string& path,
                                                      const ScanMetadata& metadata,
                                                      const std::string& config_toml,
                                                      const std::string& config_source,
                                                      const RecorderConfig& config);
  // An existing scan: reopens it, discards what came after its last checkpoint and returns the
  // map (near the last camera position when memory is bounded), the next frame id and the pose.
  static Result<std::unique_ptr<ScanRecorder>> resume(const std::string& path,
                                                      const RecorderConfig& config,
                                                      ResumePoint* resume);
  ~ScanRecorder();

  // After resume() and IncrementalReconstructor::reset() (which empties the relocaliser): puts the
  // stored keyframes back as relocalisation keyframes, so that a camera that moved while the scan
  // was down is found again. Only keyframes of the checkpoint resumed from count, with their poses
  // as stored (refined ones after `depthfuse refine`). Newest first, a keyframe is decoded and
  // measured only when its pose is wanted (IncrementalReconstructor::keyframe_wanted: the spacing
  // rule, at most relocalisation.max_keyframes kept; at most twice that many decoded, should many
  // fail their checks). With bounded memory, the evicted chunks each restored keyframe sees are
  // loaded while the map is under the pager's low watermark: a candidate pose is verified by
  // tracking against the map there (`load_views` false leaves that out: tests compare). A keyframe
  // that fails its checks is skipped and named in the report; only a failure of the file itself is
  // an error.
  Result<KeyframeRestoreReport> restore_keyframes(IncrementalReconstructor& reconstructor,
                                                  bool load_views = true);

  // The second half of a resume, after reconstructor.reset(map, next_frame_id, pose) from the
  // ResumePoint: fuses the frame redo log's records after the checkpoint, in frame order, each at
  // its stored pose (no tracking), and records them (poses, keyframes, paging) as if just fused,
  // so that the map, the next frame id and the last pose are those of the last logged frame.
  // Returns how many frames it replayed. A damaged record ends the replay (the frames before it
  // count) and is logged; it and the records after it are dropped. Until it has run, a resumed
  // recorder refuses record_frame() when the file has records to replay.
  Result<size_t> replay_log(IncrementalReconstructor& reconstructor);
  // Waits until every recorded frame's log record is committed (tests; a clean stop needs none:
  // finish() writes a checkpoint). Ok without a log.
  Status flush_frame_log();

  // Before IncrementalReconstructor::process(frame): brings back the evicted chunks the frame can
  // touch from `T_world_cam_initial` (IncrementalReconstructor::initial_pose; bounded memory only,
  // free otherwise).
  Status prepare_frame(const Frame& frame, const Pose& T_world_cam_initial,
                       IncrementalReconstructor& reconstructor);

  // After IncrementalReconstructor::process: buffers the pose, writes a keyframe every n frames,
  // and lets the pager evict what the budget cannot hold.
  Status record_frame(const Frame& frame, const FrameReport& report, PointMap* map);
  // For a frame that was not fused (tracking lost): nothing is recorded, but the pager evicts
  // what the budget cannot hold, around the pose the frame was tried at. `frame_id`: the id
  // prepare_frame() loaded for; `other_bytes`: FrameReport::graph_memory_bytes.
  Status keep_within_budget(PointMap* map, const Eigen::Vector3f& camera_m, uint32_t frame_id,
                            size_t other_bytes);

  // The pose graph the next checkpoint writes (FramePath::checkpoint_state()), in the same
  // transaction as the chunks: a resume finds the two agreeing. An empty graph (no keyframes yet,
  // or a scan without loop closure) is not written.
  void set_graph(GraphCheckpoint graph) { graph_ = std::move(graph); }
  // Where the points pending for chunks that have not followed a loop closure yet come from (the
  // map's deformation: MapDeformation::pending()). Every checkpoint stores them as they are at its
  // snapshot, beside the chunks, so that none has to bring those chunks up to date first. None
  // set: nothing is pending.
  void set_pending_points(std::function<std::vector<PendingPoints>()> source) {
    pending_source_ = std::move(source);
  }
  // A loop closure applied before frame `before_frame` was fused: the poses (and keyframe poses)
  // of the frames before it move with their keyframes, in the file at the next checkpoint.
  void poses_corrected(const AppliedCorrection& correction, uint32_t before_frame);

  // One transaction: changed resident chunks, chunks removed from the map since the last
  // checkpoint, chunks evicted since the last checkpoint, buffered poses, the poses moved by loop
  // closures, the pose graph and the counters.
  Result<CheckpointRecord> checkpoint(PointMap* map, const std::string& reason,
                                      const FrameCounters& counters = {});

  // The same checkpoint without stalling the caller: takes the changed resident chunks (their
  // points shared, copy-on-write: Chunk::points_for_write()), the keys that left the map and the
  // buffered poses, and a thread of the recorder's encodes and writes
  // them (the transaction holds the map as of the last recorded frame; see
  // ScanStore::begin_checkpoint). False when the previous one is still in flight: nothing is
  // started. Its outcome reaches status() at the next call after its commit; a failure leaves
  // everything pending for the next checkpoint, as with checkpoint().
  bool checkpoint_in_background(PointMap* map, const std::string& reason,
                                const FrameCounters& counters = {});
  bool checkpoint_in_flight() const;

  // End of scan, after IncrementalReconstructor::finish() post-filtered the resident map: applies
  // the same post-filter to evicted chunks (one at a time) and writes a final checkpoint.
  Result<CheckpointRecord> finish(PointMap* map, const FrameCounters& counters = {},
                                  const std::string& reason = "final");

  const RecorderStatus& status() const { return status_; }
  // The calling thread's connection to the file (the recorder's own threads have theirs): reads
  // see the last committed transaction of any of them.
  ScanStore& store() { return *store_; }
  MapPager* pager() { return pager_.get(); }
  uint32_t last_frame_id() const { return last_frame_id_; }
  // Recorded since the last checkpoint (after replay_log: the replayed frames' too).
  const std::vector<PoseRecord>& pending_poses() const { return pending_poses_; }

 private:
  ScanRecorder(std::unique_ptr<ScanStore> store, const RecorderConfig& config);
  // The frame log's thread on a connection of its own (with frame_log_interval_s > 0).
  Status start_frame_log();
  Status note(Status st);
  Result<CheckpointRecord> write_checkpoint(PointMap* map, const std::string& reason,
                                            const FrameCounters& counters, bool postfilter_evicted);
  CheckpointInfo checkpoint_info(const std::string& reason, const FrameCounters& counters) const;
  // Chunks that were in the map at the last checkpoint and have left it without being evicted.
  std::vector<ChunkKey> removed_chunks(const PointMap& map) const;
  // `last_frame_id`: the failed checkpoint's, which its error names.
  Status checkpoint_failed(const Status& error, uint32_t last_frame_id);
  void checkpoint_committed(const CheckpointRecord& rec, std::vector<ChunkKey> resident);
  // A background checkpoint that wrote nothing: what it held is pending again.
  void not_written(const CheckpointJob& job, const Status& why);
  // With the mutex held: applies a finished background checkpoint's outcome to the map and status.
  // `clear_dirty`: the chunks it wrote and no later frame touched are clean. Not when the map may
  // have changed outside fusion since (the end of scan's post-filter touches no frame).
  void collect_background(PointMap* map, bool clear_dirty = true);
  // Collects a finished background checkpoint's outcome, and writes the pending keyframes unless
  // another thread's transaction has the file (then they wait, up to kMaxPendingKeyframes).
  Status catch_up(PointMap* map);
  Status write_pending_keyframes();

  std::unique_ptr<ScanStore> store_;
  RecorderConfig config_;
  std::unique_ptr<MapPager> pager_;
  std::vector<PoseRecord> pending_poses_;
  std::vector<PoseCorrection> corrections_;  // since the last checkpoint, oldest first
  std::optional<GraphCheckpoint> graph_;
  std::function<std::vector<PendingPoints>()> pending_source_;
  std::vector<Keyframe> pending_keyframes_;  // taken while the writer held the store
  std::vector<ChunkKey> resident_at_checkpoint_;  // to notice chunks removed from the map
  uint32_t last_frame_id_ = 0;
  std::optional<Pose> last_pose_;
  uint64_t frames_fused_ = 0;                // including those before a resume
  uint64_t frames_since_keyframe_ = 0;
  RecorderStatus status_;
  std::unique_ptr<CheckpointWriter> writer_;  // created by the first background checkpoint
  std::unique_ptr<FrameLogWriter> frame_log_;  // with frame_log_interval_s > 0
  bool replay_pending_ = false;              // resumed with log records not yet replayed
  bool replaying_ = false;                   // replay_log() records frames that are logged already
};

}  // namespace depthfuse::store
