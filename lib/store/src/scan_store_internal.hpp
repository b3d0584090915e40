// Internal: what the units of ScanStore share. The object behind a ScanStore (its connection,
// writer lock, codec and transaction state), the rows of the chunk and checkpoint tables, and the
// SQL that says which frames the last checkpoint holds.
//
// ScanStore's work is split by job, each unit on this one Impl:
//   scan_store.cpp             the Impl's shared pieces: transactions, meta rows, chunk rows
//   scan_store_open.cpp        opening: the writer lock, creating, migrating, recovering
//   scan_store_checkpoint.cpp  writing: checkpoints, chunks, poses, keyframes, staging
//   scan_store_read.cpp        reading: snapshots, chunks, poses, keyframes, checkpoints, summary
//   scan_store_integrity.cpp   checking every table and blob
//   scan_store_frame_log.cpp   the frame redo log: appending, reading, dropping records
// A ScanStore is one connection and belongs to one thread: the fusion daemon's worker thread owns
// the writer (through ScanRecorder), whose background checkpoint and frame log threads write on
// connections of their own (ScanStore::another_connection); readers are other processes
// (depthfuse export and inspect), each with its own connection.
#pragma once

#include <sys/stat.h>

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <initializer_list>
#include <utility>
#include <vector>

#include "depthfuse/store/blob_codec.hpp"
#include "depthfuse/store/scan_store.hpp"
#include "sqlite_db.hpp"

namespace depthfuse::store {

// The column lists of the tables' rows, each with the indices of its columns in a row read with
// it (a statement's parameters are numbered from 1: param()). Every index is checked against its
// list's column of that name when this compiles.

// The `index`-th column of a comma-separated list; empty past the last.
constexpr std::string_view column_at(std::string_view list, int index) {
  size_t begin = 0;
  for (; index > 0; --index) {
    begin = list.find(',', begin);
    if (begin == std::string_view::npos) return {};
    ++begin;
  }
  std::string_view item = list.substr(begin, list.find(',', begin) - begin);
  while (!item.empty() && item.front() == ' ') item.remove_prefix(1);
  return item;
}
// The index of the column `name`, -1 when the list has none.
constexpr int column_index(std::string_view list, std::string_view name) {
  for (int i = 0; !column_at(list, i).empty(); ++i)
    if (column_at(list, i) == name) return i;
  return -1;
}
// The columns of `names` are the list's from `first` on, in that order.
constexpr bool columns_at(std::string_view list, int first, std::string_view names) {
  int i = 0;
  for (; !column_at(names, i).empty(); ++i)
    if (column_index(list, column_at(names, i)) != first + i) return false;
  return i > 0;
}
// The list has `count` columns, and each named one is at its index.
constexpr bool columns_named(std::string_view list, int count,
                             std::initializer_list<std::pair<int, std::string_view>> named) {
  if (!column_at(list, count).empty() || column_at(list, count - 1).empty()) return false;
  for (const auto& [index, name] : named)
    if (column_index(list, name) != index) return false;
  return true;
}
constexpr int param(int column) { return column + 1; }

// The columns of a chunk row up to the one that differs between the tables (chunks:
// checkpoint_id; chunk_staging: staged_utime). A row of select_chunks() has them, then the
// checkpoint id (0 when staged), then the blob or an expression on it; an INSERT names them with
// the column that differs, then `data`.
inline constexpr const char* kChunkColumns =
    "x, y, z, point_count, min_x, min_y, min_z, max_x, max_y, max_z, last_touched_frame, version, "
    "checksum";
struct ChunkCol {
  enum : int {
    kX, kY, kZ, kPointCount, kMinX, kMinY, kMinZ, kMaxX, kMaxY, kMaxZ, kLastTouchedFrame, kVersion,
    kChecksum, kCheckpointId, kData
  };
};
static_assert(columns_named(kChunkColumns, ChunkCol::kCheckpointId, {{ChunkCol::kX, "x"},
              {ChunkCol::kY, "y"}, {ChunkCol::kZ, "z"}, {ChunkCol::kPointCount, "point_count"},
              {ChunkCol::kMinX, "min_x"}, {ChunkCol::kMinY, "min_y"}, {ChunkCol::kMinZ, "min_z"},
              {ChunkCol::kMaxX, "max_x"}, {ChunkCol::kMaxY, "max_y"}, {ChunkCol::kMaxZ, "max_z"},
              {ChunkCol::kLastTouchedFrame, "last_touched_frame"}, {ChunkCol::kVersion, "version"},
              {ChunkCol::kChecksum, "checksum"}}));

// A row of the poses table. The pose is T_world_cam, or T_kf_cam where graph_keyframe names the
// pose-graph keyframe it is relative to (PoseAnchor).
inline constexpr const char* kPoseColumns =
    "frame_id, utime, T_world_cam, registered, fitness, rmse_m, correspondences, graph_keyframe, "
    "checksum";
struct PoseCol {
  enum : int {
    kFrameId, kUtime, kPose, kRegistered, kFitness, kRmse, kCorrespondences, kAnchor, kChecksum
  };
};
static_assert(columns_named(kPoseColumns, PoseCol::kChecksum + 1, {{PoseCol::kFrameId, "frame_id"},
              {PoseCol::kUtime, "utime"}, {PoseCol::kPose, "T_world_cam"},
              {PoseCol::kRegistered, "registered"}, {PoseCol::kFitness, "fitness"},
              {PoseCol::kRmse, "rmse_m"}, {PoseCol::kCorrespondences, "correspondences"},
              {PoseCol::kAnchor, "graph_keyframe"}, {PoseCol::kChecksum, "checksum"}}));

// A row of the checkpoints table.
inline constexpr const char* kCheckpointColumns =
    "id, utime, reason, last_frame_id, frames_fused, point_count, chunk_count, "
    "T_world_cam, checksum";
struct CheckpointCol {
  enum : int {
    kId, kUtime, kReason, kLastFrameId, kFramesFused, kPointCount, kChunkCount, kPose, kChecksum
  };
};
static_assert(columns_named(kCheckpointColumns, CheckpointCol::kChecksum + 1, {
              {CheckpointCol::kId, "id"}, {CheckpointCol::kUtime, "utime"},
              {CheckpointCol::kReason, "reason"}, {CheckpointCol::kLastFrameId, "last_frame_id"},
              {CheckpointCol::kFramesFused, "frames_fused"},
              {CheckpointCol::kPointCount, "point_count"},
              {CheckpointCol::kChunkCount, "chunk_count"}, {CheckpointCol::kPose, "T_world_cam"},
              {CheckpointCol::kChecksum, "checksum"}}));

// Of a keyframe up to its images; a row read with them has the depth and the colour next (or
// expressions on them, such as their lengths). The pose is anchored as a pose row's is.
inline constexpr const char* kKeyframeColumns =
    "frame_id, utime, sensor_serial, width, height, fx, fy, cx, cy, T_world_cam, graph_keyframe, "
    "checksum";
struct KeyframeCol {
  enum : int {
    kFrameId, kUtime, kSensorSerial, kWidth, kHeight, kFx, kFy, kCx, kCy, kPose, kAnchor, kChecksum,
    kDepth, kColor
  };
};
static_assert(columns_named(kKeyframeColumns, KeyframeCol::kDepth, {
              {KeyframeCol::kFrameId, "frame_id"}, {KeyframeCol::kUtime, "utime"},
              {KeyframeCol::kSensorSerial, "sensor_serial"}, {KeyframeCol::kWidth, "width"},
              {KeyframeCol::kHeight, "height"}, {KeyframeCol::kFx, "fx"}, {KeyframeCol::kFy, "fy"},
              {KeyframeCol::kCx, "cx"}, {KeyframeCol::kCy, "cy"},
              {KeyframeCol::kPose, "T_world_cam"}, {KeyframeCol::kAnchor, "graph_keyframe"},
              {KeyframeCol::kChecksum, "checksum"}}));

// A row of the frame redo log.
inline constexpr const char* kFrameLogColumns =
    "frame_id, utime, T_world_cam, registered, fitness, rmse_m, correspondences, width, "
    "height, fx, fy, cx, cy, checksum, depth, color";
struct FrameLogCol {
  enum : int {
    kFrameId, kUtime, kPose, kRegistered, kFitness, kRmse, kCorrespondences, kWidth, kHeight, kFx,
    kFy, kCx, kCy, kChecksum, kDepth, kColor
  };
};
static_assert(columns_named(kFrameLogColumns, FrameLogCol::kColor + 1, {
              {FrameLogCol::kFrameId, "frame_id"}, {FrameLogCol::kUtime, "utime"},
              {FrameLogCol::kPose, "T_world_cam"}, {FrameLogCol::kRegistered, "registered"},
              {FrameLogCol::kFitness, "fitness"}, {FrameLogCol::kRmse, "rmse_m"},
              {FrameLogCol::kCorrespondences, "correspondences"}, {FrameLogCol::kWidth, "width"},
              {FrameLogCol::kHeight, "height"}, {FrameLogCol::kFx, "fx"}, {FrameLogCol::kFy, "fy"},
              {FrameLogCol::kCx, "cx"}, {FrameLogCol::kCy, "cy"},
              {FrameLogCol::kChecksum, "checksum"}, {FrameLogCol::kDepth, "depth"},
              {FrameLogCol::kColor, "color"}}));

// Poses and frame log records start with the same columns (read_pose_columns), keyframes and
// frame log records have the intrinsics in the same order (read_intrinsics_columns).
inline constexpr const char* kFusedFrameColumns =
    "frame_id, utime, T_world_cam, registered, fitness, rmse_m, correspondences";
inline constexpr const char* kIntrinsicsColumns = "width, height, fx, fy, cx, cy";
static_assert(columns_at(kPoseColumns, PoseCol::kFrameId, kFusedFrameColumns) &&
              columns_at(kFrameLogColumns, FrameLogCol::kFrameId, kFusedFrameColumns));
static_assert(columns_at(kKeyframeColumns, KeyframeCol::kWidth, kIntrinsicsColumns) &&
              columns_at(kFrameLogColumns, FrameLogCol::kWidth, kIntrinsicsColumns));

// The frames the last checkpoint holds, as an SQL condition on a `frame_id` column: every frame up
// to its last_frame_id (none before the first checkpoint). Readers show only these poses and
// keyframes; a writer reopening the file deletes the others.
inline const std::string kCommittedFrames =
    "frame_id <= COALESCE((SELECT last_frame_id FROM checkpoints ORDER BY id DESC LIMIT 1), 0)";

// The tables whose rows are chunks: the committed chunks, those the pager staged since, and the
// points waiting for a chunk to follow a loop closure (one row per chunk and version).
enum class ChunkTable { kChunks, kStaging, kPending };
const char* table_name(ChunkTable table);

// "SELECT <chunk columns>, <checkpoint id>, <last> FROM <table>" (a staged row's checkpoint id:
// 0). `last` is the blob or an expression on it, e.g. length(data).
std::string select_chunks(ChunkTable table, const char* last);

// A chunk row's fields read with select_chunks(), except blob_bytes.
ChunkInfo chunk_info_of(const sql::Row& row);

Eigen::AlignedBox3f bounds_of(const PointArrays& a);

// The values of a pose row that its checksum covers besides the pose blob.
PoseFields pose_fields(const PoseRecord& p);

// CRC-32 of a chunk row (chunks.checksum, chunk_staging.checksum; the blob has its own): x y z
// i32, point_count u32, last_touched_frame u32, version u32.
uint32_t chunk_row_checksum(const ChunkKey& key, uint32_t point_count, uint32_t last_touched_frame,
                            uint32_t version);

// CRC-32 of a keyframe row's pose and the values it is used with (keyframes.checksum):
// frame_id u32, utime i64, width u32, height u32, fx fy cx cy f64, the pose blob's bytes.
uint32_t keyframe_row_checksum(uint32_t frame_id, int64_t utime, const CameraIntrinsics& K,
                               const void* pose_blob, size_t pose_size);
// CRC-32 of a checkpoint row (checkpoints.checksum): id i64, utime i64, last_frame_id u32,
// frames_fused u64, point_count u64, chunk_count u64, the reason's length u32 and bytes, the pose
// blob's bytes (none when NULL).
uint32_t checkpoint_row_checksum(const CheckpointRecord& r, const void* pose_blob, size_t pose_size);
// CRC-32 of a frame log row (frame_log.checksum): the pose row's fields as poses.checksum has them
// (pose_record_checksum), then width u32, height u32, fx fy cx cy f64, the depth blob's length u32
// and bytes, the colour blob's length u32 and bytes (0 and none without colour).
uint32_t frame_log_row_checksum(const PoseRecord& p, const void* pose_blob, size_t pose_size,
                                const CameraIntrinsics& K, const void* depth, size_t depth_size,
                                const void* color, size_t color_size);
// The columns every row of a fused frame starts with (PoseCol: poses, frame_log): frame_id, utime,
// the pose blob (left to the caller, who checks the row's checksum first), registered, fitness,
// rmse_m, correspondences. The frame id's range is the caller's to check.
void read_pose_columns(const sql::Row& row, PoseRecord* p);
// Pinhole intrinsics from six columns starting at `first`: width, height, fx, fy, cx, cy.
CameraIntrinsics read_intrinsics_columns(const sql::Row& row, int first);
// And into six parameters starting at `first`.
void bind_intrinsics(sql::Statement& st, int first, const CameraIntrinsics& K);

// The frame a stored pose (poses, keyframes) is in: none, the world; k, the pose graph's keyframe
// k as the file's graph row has it (the blob is then T_kf_cam). A checkpoint stores the poses of a
// keyframe's segment relative to it, so that a correction, which moves the keyframes in the graph
// row, moves every stored pose without rewriting its row: the rows a correction rewrote grew with
// the scan, and the checkpoint after each closure held the file for longer and longer.
using PoseAnchor = std::optional<uint32_t>;
// The row's anchor column; a value out of range is damage.
Result<PoseAnchor> read_anchor(const sql::Row& row, int column, const std::string& what);
void bind_anchor(sql::Statement& st, int param, const PoseAnchor& anchor);
// A row checksum that covers the row's anchor too: unchanged for a row in the world frame (as
// rows were written before schema 7), else the CRC-32 of (that checksum u32, the keyframe u32).
uint32_t with_anchor(uint32_t checksum, const PoseAnchor& anchor);

// "<what>: checksum mismatch (stored 0x…, computed 0x…)"
Status checksum_mismatch(const std::string& what, uint32_t stored, uint32_t computed);
// The row's checksum column at `column` against `computed`; NULL (written before the column
// existed) passes and sets *unchecked.
Status check_row_checksum(const sql::Row& row, int column, uint32_t computed, const std::string& what,
                          bool* unchecked = nullptr);

inline bool file_exists(const std::string& path) {
  struct stat st {};
  return ::stat(path.c_str(), &st) == 0;
}

struct ScanStore::Impl {
  std::string path;
  OpenMode mode = OpenMode::kReadOnly;
  StoreOptions options;
  sql::Database db;
  int lock_fd = -1;                // the writer lock (flock), -1 when read-only
  int schema_version = 0;
  OpenReport report;
  BlobCodec codec;
  bool in_checkpoint = false;
  int64_t checkpoint_id = 0;       // of the open checkpoint
  uint32_t checkpoint_up_to_frame = kAllFrames;  // of the open checkpoint
  int read_depth = 0;              // nested begin_read calls
  EncodedChunk encoded;            // scratch for encoding chunks
  // The graph row's keyframe poses that anchored poses are relative to, and the row they were
  // read from (its checkpoint id and checksum: a new checkpoint replaces the row).
  struct Anchors {
    int64_t checkpoint_id = -1, checksum = -1;
    std::vector<Pose> T_world_kf;
  } anchors;

  explicit Impl(int level) : codec(level) {}
  ~Impl();

  bool writable() const { return mode != OpenMode::kReadOnly; }
  Status require_writable(const char* what) const {
    if (!writable()) return invalid_argument(path + ": " + what + ": the scan is open read-only");
    return Status::ok();
  }

  // Runs fn inside the open checkpoint, or else in a transaction of its own.
  template <typename Fn>
  Status in_transaction(const std::string& ctx, Fn&& fn) {
    if (in_checkpoint) return fn();
    return db.transaction(ctx, std::forward<Fn>(fn));
  }
  // FULL while a checkpoint (or a migration or recovery) commits: its commit record is fsynced
  // before COMMIT returns. NORMAL otherwise.
  Status set_synchronous(const char* level);

  // scan_store.cpp
  Status set_meta(const std::vector<std::pair<std::string, std::string>>& kv);
  Result<std::optional<std::string>> get_meta(const std::string& key);
  Status write_chunk_row(ChunkTable table, const ChunkKey& key, const Chunk& chunk,
                         int64_t last_column);
  Status write_chunk_row(ChunkTable table, const EncodedChunk& chunk, int64_t last_column);
  // scan_store_checkpoint.cpp: a pose row, and a keyframe row's pose; `p.T_world_cam` and `T` are
  // as stored (T_kf_cam when anchored).
  Status write_pose_row(const PoseRecord& p, const PoseAnchor& anchor);
  Status set_keyframe_pose(uint32_t frame_id, const Pose& T, const PoseAnchor& anchor);
  // Inside a checkpoint: deletes the staged copy of `key` unless a frame after the checkpoint's
  // touched it, and with `committed` the checkpointed row too.
  Status delete_chunk_rows(const ChunkKey& key, bool committed);
  // Reads a row of select_chunks(table, "data") and decodes its blob into `out`.
  Status decode_chunk_row(const sql::Row& row, ChunkTable table, StoredChunk* out);
  // The first columns of a keyframe row (kKeyframeColumns): everything but the images, the
  // intrinsics valid, the checksum checked (`*unchecked` when the row has none) and the pose
  // decoded.
  // The pose is in the world frame (an anchored one resolved with `T_world_kf`, graph_anchors()).
  Status keyframe_head_of(const sql::Row& row, const std::vector<Pose>& T_world_kf, Keyframe* out,
                          bool* unchecked = nullptr);
  // A row of kCheckpointColumns, its checksum checked.
  Result<CheckpointRecord> checkpoint_of(const sql::Row& row);
  // A row of kPoseColumns: decoded and, when it has one, its checksum checked. `*checked` says
  // whether it had one. The pose is in the world frame, as keyframe_head_of's.
  Result<PoseRecord> pose_of(const sql::Row& row, const std::vector<Pose>& T_world_kf,
                             bool* checked = nullptr);
  // The keyframe poses of the graph row, which anchored poses are relative to (none without a
  // graph); read again only when the row has changed. Inside the caller's read snapshot.
  Result<const std::vector<Pose>*> graph_anchors();
  // How many of the stored graph's keyframes `keyframes` begins with: all of them, or kReplaced
  // when it does not continue the stored graph (scan_store_graph.cpp).
  static constexpr size_t kReplaced = ~size_t{0};
  Result<size_t> stored_graph_keyframes(const std::vector<GraphKeyframe>& keyframes);
  // Every anchored pose back into the world frame, as the stored graph row has its keyframes.
  Status unanchor_poses();
  // An anchored pose (T_kf_cam) into the world frame; an anchor the graph does not have is damage.
  Status resolve_anchor(const PoseAnchor& anchor, const std::vector<Pose>& T_world_kf, Pose* T,
                        const std::string& what) const;

  // scan_store_open.cpp
  Status open_existing();
  Status create_new();
  Status lock_for_writing();
  Status recover();
};

}  // namespace depthfuse::store
