// The scan file: one SQLite database per scan holding the fused cloud by chunk, the poses, the
// keyframes (losslessly compressed depth for offline refinement), scan metadata and the
// configuration in use. Format, versions and durability: docs/checkpoint-format.md.
//
// Writing happens in checkpoints, each one transaction (WAL, committed with synchronous=FULL): after
// a crash or power loss the file holds exactly the last committed checkpoint. Between checkpoints
// the memory pager may stage evicted chunks and keyframes in the file; those are promoted by the
// next checkpoint, and discarded when a writer reopens the file after a crash (they belong to
// frames after the last checkpoint). Readers (export, inspect) see the last checkpoint only, and can
// run while the daemon writes.
//
// One writer per file (an advisory lock, so a second writer gets kUnavailable); any number of
// readers. A ScanStore is one SQLite connection and belongs to one thread: a writer whose work
// runs on several threads gives each its own connection (another_connection), and SQLite orders
// their transactions (WAL: one writer at a time, readers never wait). docs/checkpoint-format.md,
// "Who uses the file".
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "depthfuse/frame_path.hpp"
#include "depthfuse/map_deformation.hpp"
#include "depthfuse/point_map.hpp"
#include "depthfuse/scan_graph.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/store/blob_codec.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::store {

constexpr int kSchemaVersion = 8;                 // PRAGMA user_version of files written now
constexpr int32_t kApplicationId = 0x44465343;    // PRAGMA application_id: "DFSC"

enum class OpenMode {
  kCreate,     // a new file; fails if it exists
  kReadWrite,  // an existing file: migrates an older schema, discards work after the last checkpoint
  kReadOnly,   // never writes; works while a writer is active
};

struct StoreOptions {
  int compression_level = 3;     // zstd level of chunk and keyframe blobs
  int busy_timeout_ms = 5000;    // wait this long for a lock held by another connection
};

struct ScanMetadata {
  std::string scan_id;
  int64_t created_utime = 0;     // microseconds since the Unix epoch
  std::string sensor_serial;
  std::string method;            // to_string(Method)
  double chunk_size_m = 0.5;     // of the PointMap the chunks come from
  std::string software_version;
  uint64_t frames_received = 0;
  uint64_t frames_fused = 0;
  uint64_t frames_tracked_only = 0;  // placed but not fused: fusion was behind the camera
  uint64_t frames_lost = 0;          // tracking lost: neither placed nor fused
  uint64_t frames_dropped = 0;       // the daemon's queue overflowed
};

// One fused frame's pose and how well it registered.
struct PoseRecord {
  uint32_t frame_id = 0;
  int64_t utime = 0;
  Pose T_world_cam = Pose::Identity();
  bool registered = false;       // ICP converged
  double fitness = 0.0;
  double rmse_m = 0.0;
  uint32_t correspondences = 0;
};

// A frame kept for offline refinement: depth (lossless), optional colour, intrinsics and pose.
struct Keyframe {
  uint32_t frame_id = 0;
  int64_t utime = 0;
  std::string sensor_serial;
  CameraIntrinsics intrinsics;
  Pose T_world_cam = Pose::Identity();
  DepthImage depth;
  ColorImage color;              // empty when not stored

  static Keyframe from_frame(const Frame& frame, uint32_t frame_id, const Pose& T_world_cam,
                             bool keep_color);
  // A Frame for the pipeline; the stored pose becomes the frame's pose hint.
  Frame to_frame() const;
};

struct KeyframeInfo {
  uint32_t frame_id = 0;
  int64_t utime = 0;
  int width = 0, height = 0;
  Pose T_world_cam = Pose::Identity();
  size_t depth_bytes = 0, color_bytes = 0;   // stored (compressed) sizes
};

struct ChunkInfo {
  ChunkKey key;
  uint32_t point_count = 0;
  Eigen::AlignedBox3f bounds_m;              // of the points; empty for an empty chunk
  uint32_t last_touched_frame = 0;
  uint32_t version = 0;                      // the graph version of its points (Chunk::version)
  int64_t checkpoint_id = 0;                 // the checkpoint that wrote it (0 = staged)
  size_t blob_bytes = 0;
  bool checksummed = true;                   // false: a row written before schema 6
};

// A chunk encoded ahead of the checkpoint that writes it (a checkpoint written in the background
// encodes before it takes the store, so that the fusion thread's own writes do not wait for it).
struct EncodedChunk {
  ChunkKey key;
  uint32_t point_count = 0;
  Eigen::AlignedBox3f bounds_m;              // empty for an empty chunk
  uint32_t last_touched_frame = 0;
  uint32_t version = 0;
  std::vector<uint8_t> blob;                 // DFB1 points
};
Status encode_chunk(BlobCodec& codec, const ChunkKey& key, const Chunk& chunk, EncodedChunk* out);
// Points pending for a chunk (MapDeformation::pending()), encoded as a chunk row of their version
// (last_touched_frame 0).
Status encode_pending(BlobCodec& codec, const PendingPoints& pending, EncodedChunk* out);

// One fused frame of the frame redo log, encoded: what replaying it needs. Its pose is the one it
// was fused at (no tracking on replay), its depth and colour the DFB1 blobs of keyframes.
struct FrameLogRecord {
  PoseRecord pose;                           // frame id, utime, T_world_cam as fused, ICP figures
  CameraIntrinsics intrinsics;
  std::vector<uint8_t> depth;                // DFB1 depth (lossless)
  std::vector<uint8_t> color;                // DFB1 colour; empty when the frame had none
};
// Encodes `frame` (fused as `pose`) into `out`, reusing its buffers.
Status encode_frame_log_record(BlobCodec& codec, const PoseRecord& pose, const Frame& frame,
                               FrameLogRecord* out);

// A logged frame decoded: the frame (no pose hint) and the pose it was fused at.
struct LoggedFrame {
  PoseRecord pose;
  Frame frame;
};

// The redo log's records after the last checkpoint: what a resume replays.
struct FrameLogSummary {
  size_t count = 0;
  uint32_t first_frame_id = 0, last_frame_id = 0;   // 0 when empty
  size_t stale = 0;                          // covered by the last checkpoint (a writer drops them)
  uint64_t bytes = 0;                        // stored blob sizes of the `count` records
};

// "Every frame": a checkpoint that takes all staged chunks.
constexpr uint32_t kAllFrames = 0xFFFFFFFFu;

struct StoredChunk {
  ChunkInfo info;
  Chunk chunk;                               // dirty = false: it is what the file holds
};

// What a checkpoint records besides the chunks, poses and keyframes written into it.
struct CheckpointInfo {
  std::string reason = "periodic";           // periodic | command | sigterm | final | refine | ...
  uint32_t last_frame_id = 0;                // every frame up to this one is in the checkpoint
  std::optional<Pose> T_world_cam;           // camera at the checkpoint (where a resume starts)
  uint64_t frames_received = 0, frames_fused = 0, frames_tracked_only = 0, frames_lost = 0,
           frames_dropped = 0;
};

struct CheckpointRecord {
  int64_t id = 0;                            // 1, 2, 3 ...
  int64_t utime = 0;                         // wall clock at commit
  std::string reason;
  uint32_t last_frame_id = 0;
  uint64_t frames_fused = 0;
  uint64_t point_count = 0, chunk_count = 0;
  std::optional<Pose> T_world_cam;
};

// What the last checkpoint holds of the pose graph (inspect).
struct GraphSummary {
  int64_t checkpoint_id = 0;                 // the checkpoint that wrote it
  uint32_t version = 0;                      // corrections applied
  size_t keyframes = 0, loops = 0;
  uint32_t deformation_version = 0;          // the map's: the graph's version once it follows
  uint32_t deformation_oldest_version = 0;   // history kept from (evicted chunks need it)
  uint64_t keyframe_bytes = 0, state_bytes = 0;  // stored blob sizes
};

// A loop closure applied to the poses of the frames before `before_frame` (the first frame fused
// after it), for the poses already written (ScanStore::write_poses).
struct PoseCorrection {
  AppliedCorrection correction;
  uint32_t before_frame = 0;
};

// What opening read-write did to the file.
struct OpenReport {
  int found_schema_version = 0;
  bool migrated = false;
  size_t discarded_staged_chunks = 0;        // staged after the last checkpoint (crash)
  size_t discarded_poses = 0, discarded_keyframes = 0;
  size_t discarded_log_records = 0;          // redo log records the last checkpoint covers
};

struct StoreSummary {
  std::string path;
  int schema_version = 0;
  ScanMetadata metadata;
  bool has_config = false;
  size_t chunk_count = 0;
  uint64_t point_count = 0;
  Eigen::AlignedBox3f extent_m;              // empty without points
  size_t pose_count = 0, keyframe_count = 0;
  size_t checkpoint_count = 0;
  std::optional<CheckpointRecord> last_checkpoint;
  std::optional<GraphSummary> graph;         // none: the scan has no pose graph (or a damaged one)
  std::string graph_problem;                 // why the graph could not be read; empty when it could
  size_t staged_chunk_count = 0;             // evicted since the last checkpoint
  // Points waiting for their chunk to follow a correction (rows: chunk and version).
  size_t pending_rows = 0;
  uint64_t pending_points = 0;
  uint64_t chunk_bytes = 0, keyframe_bytes = 0;  // stored blob sizes
  uint64_t file_bytes = 0, wal_bytes = 0;
};

struct IntegrityReport {
  bool ok() const { return problems.empty(); }
  std::vector<std::string> problems;         // each names the table/row/column at fault
  size_t chunks_checked = 0, keyframes_checked = 0, poses_checked = 0;
  size_t graph_keyframes_checked = 0;        // the pose graph's keyframe rows
  size_t pending_rows_checked = 0;           // points pending for a correction (chunk_pending)
  // Of chunks_checked: rows written before schema 6, without a checksum (and at version 0).
  size_t chunks_unchecked = 0;
  // Of poses_checked: rows written before schema 3, without a checksum. Their pose decodes (96
  // bytes, finite, a rotation) but a changed value cannot be told from a true one.
  size_t poses_unchecked = 0;
  // Keyframe and checkpoint rows written before schema 4, whose poses have no checksum.
  size_t keyframes_unchecked = 0, checkpoints_unchecked = 0;
  // The frame redo log after the last checkpoint: records whose checksum and blobs were checked,
  // and its summary.
  size_t log_records_checked = 0;
  FrameLogSummary frame_log;
};

// Chunk iteration options.
struct ChunkFilter {
  // Only chunks whose bounds intersect this box (SQL-side, nothing else is decoded).
  std::optional<Eigen::AlignedBox3f> bbox_m;
  // When set, a chunk whose blob fails its checks is reported here and skipped (salvage);
  // otherwise iteration stops with that error.
  std::function<void(const Status&)> on_damaged;
};

class ScanStore {
 public:
  static Result<std::unique_ptr<ScanStore>> open(const std::string& path, OpenMode mode,
                                                 const StoreOptions& options = {});
  // Another connection to this store's file, for another thread of this process. It neither checks
  // nor locks the file, nor migrates or recovers it: this store did, and its writer lock stands
  // for both (an open and close of the file here would drop the process's locks on it). Writable
  // when this store is. `options.busy_timeout_ms`: how long its transactions wait for the
  // other connections' (0: kUnavailable at once).
  Result<std::unique_ptr<ScanStore>> another_connection(const StoreOptions& options) const;
  ~ScanStore();
  ScanStore(const ScanStore&) = delete;
  ScanStore& operator=(const ScanStore&) = delete;

  const std::string& path() const;
  bool read_only() const;
  int schema_version() const;
  const OpenReport& open_report() const;

  // ---- Metadata and configuration (inside a checkpoint, or each its own transaction).
  Status set_metadata(const ScanMetadata& meta);
  Result<ScanMetadata> metadata();
  Status set_config(const std::string& toml_text, const std::string& source_path);
  // Empty optional when the scan has none.
  Result<std::optional<std::string>> config_toml();

  // ---- Checkpoints: begin, write, commit. Nothing is visible to readers before commit; a failed
  // write or commit rolls the whole checkpoint back and the previous one stays intact.
  // `up_to_frame`: the checkpoint holds the map as of this frame. Staged chunks last touched by a
  // later frame (the pager evicted them while the checkpoint was being written in the background)
  // are neither promoted nor replaced by it: they stay staged for the next checkpoint.
  Status begin_checkpoint(uint32_t up_to_frame = kAllFrames);
  // An empty chunk deletes the key. Replaces a staged copy of the same key (one of the checkpoint's
  // frames).
  Status write_chunk(const ChunkKey& key, const Chunk& chunk);
  Status write_chunk(const EncodedChunk& chunk);
  Status delete_chunk(const ChunkKey& key);
  Status delete_all_chunks();                       // e.g. refine replaces the cloud
  Status write_pose(const PoseRecord& pose);        // insert or replace by frame id
  Status update_keyframe_pose(uint32_t frame_id, const Pose& T_world_cam);
  // Promotes staged chunks, records the checkpoint, commits with a full sync.
  Result<CheckpointRecord> commit_checkpoint(const CheckpointInfo& info);
  void rollback_checkpoint();
  bool in_checkpoint() const;

  // Inside a checkpoint it joins it; outside, its own (not fsynced) transaction. Keyframes newer
  // than the last checkpoint are discarded when a writer reopens after a crash.
  Status write_keyframe(const Keyframe& keyframe);

  // ---- The pose graph (scan_store_graph.cpp). Inside a checkpoint: appends the keyframes not
  // stored yet (a keyframe's cloud and odometry edge never change), replaces the keyframes'
  // poses, the loop edges, the version and the deformation's history.
  Status write_graph(const GraphCheckpoint& graph);
  // Inside a checkpoint, with the graph's `keyframes` as the checkpoint writes them: the poses of
  // the checkpoint's frames (`fused`, as they were fused) and every stored pose (poses, keyframes)
  // still in the world frame, from the first keyframe's frame on, move by the corrections made
  // after their frame was fused (those whose before_frame is later, in order) and are stored
  // relative to the keyframe whose segment holds their frame. Readers see them moved by every
  // later correction of that keyframe without their rows being written again. Without keyframes,
  // the poses are stored as they are.
  Status write_poses(const std::vector<PoseRecord>& fused,
                     const std::vector<PoseCorrection>& corrections,
                     const std::vector<GraphKeyframe>& keyframes);
  // The last checkpoint's graph, every row's checksum and blob checked (kCorrupt naming the row);
  // none when the scan has none.
  Result<std::optional<GraphCheckpoint>> read_graph();
  // Inside a checkpoint: the points pending for chunks that had not followed the graph's last
  // correction (MapDeformation::pending(), encoded), replacing those stored.
  Status write_pending(const std::vector<EncodedChunk>& pending);
  Status write_pending(const std::vector<PendingPoints>& pending);  // encoded here
  // The last checkpoint's pending points, by key then version, every row checked (kCorrupt naming
  // it).
  Result<std::vector<PendingPoints>> read_pending();
  Result<std::optional<GraphSummary>> graph_summary();

  // ---- The frame redo log (scan_store_frame_log.cpp). Records are appended in one transaction
  // committed with a full sync (inside an open checkpoint they join it); a checkpoint's commit
  // deletes the records its frames cover. Readers and resumes use only the records after the last
  // checkpoint.
  Status append_frame_log(const std::vector<FrameLogRecord>& records);
  Result<FrameLogSummary> frame_log_summary();
  // The records after the last checkpoint in frame order, each checked (row checksum, blobs) and
  // decoded before `fn` sees it. A record that fails a check ends the iteration with its kCorrupt
  // status naming the frame, after `fn` had every record before it.
  // `after_frame_id` and `limit` read a part: the records after that frame, at most `limit`.
  Status for_each_logged_frame(const std::function<Status(LoggedFrame&)>& fn,
                               uint32_t after_frame_id = 0, size_t limit = 0);
  // Drops the records from `frame_id` on (a resume after a damaged record: they cannot be
  // replayed, and the frames fused next take their ids).
  Status discard_frame_log_from(uint32_t frame_id);

  // ---- Staging for the memory pager: one transaction for the batch; not allowed inside a
  // checkpoint (a rollback would lose chunks already dropped from memory).
  Status stage_chunks(const std::vector<std::pair<ChunkKey, const Chunk*>>& chunks);

  // ---- Reading. Each call is consistent on its own; wrap several in begin_read/end_read to see
  // one snapshot (export counts and then writes the same points).
  Status begin_read();
  void end_read();

  // The newest copy: a staged chunk if there is one (pager), else the committed one.
  Result<StoredChunk> read_chunk(const ChunkKey& key, bool include_staged = false);
  Result<std::vector<ChunkInfo>> list_chunks(bool include_staged = false);
  // Committed chunks in key order, one decoded at a time. The callback may move the points.
  Status for_each_chunk(const std::function<Status(const ChunkInfo&, PointArrays&)>& fn,
                        const ChunkFilter& filter = {});
  // Each row's checksum is checked (kCorrupt naming the frame); rows written before schema 3 have
  // none and are taken as they are.
  Result<std::vector<PoseRecord>> read_poses();
  // Each row's checksum is checked; with `on_damaged` a row that fails is reported there and left
  // out (a resume restoring relocalisation keyframes), otherwise the listing fails with it.
  Result<std::vector<KeyframeInfo>> list_keyframes(
      const std::function<void(const Status&)>& on_damaged = nullptr);
  Result<Keyframe> read_keyframe(uint32_t frame_id);
  Result<std::optional<CheckpointRecord>> last_checkpoint();
  Result<std::vector<CheckpointRecord>> checkpoints();
  Result<StoreSummary> summary();
  // Returns pages freed by deleted chunks to the file system (files created with schema 2 use
  // incremental auto-vacuum). Not inside a checkpoint.
  Status compact();
  // A compact copy of the file as of now (VACUUM INTO); `path` must not exist. Works read-only.
  Status copy_to(const std::string& path);
  // Whether the stored frame numbers agree with each other: checkpoints in order (frames and
  // counts never going back), the last checkpoint's frame is its newest pose's, no more poses than
  // frames fused. Each disagreement is a problem naming the values; a writer does not resume a
  // scan that has any.
  std::vector<std::string> frame_problems();
  // PRAGMA integrity_check, frame_problems(), and decoding and checking every blob (`check_blobs`).
  Result<IntegrityReport> integrity_check(bool check_blobs = true);

  struct Impl;

 private:
  explicit ScanStore(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// Begins a read snapshot and ends it when it goes out of scope.
class ScopedRead {
 public:
  explicit ScopedRead(ScanStore& store) : store_(store), status_(store.begin_read()) {}
  ~ScopedRead() {
    if (status_.is_ok()) store_.end_read();
  }
  const Status& status() const { return status_; }

 private:
  ScanStore& store_;
  Status status_;
};

std::string to_string(const ChunkKey& key);  // "(1,-2,3)"

}  // namespace depthfuse::store
