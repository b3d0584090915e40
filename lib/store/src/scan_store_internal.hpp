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
#include <utility>
#include <vector>

#include "depthfuse/store/blob_codec.hpp"
#include "depthfuse/store/scan_store.hpp"
#include "sqlite_db.hpp"

namespace depthfuse::store {

// The columns of a chunk row up to the one that differs between the tables (chunks:
// checkpoint_id; chunk_staging: staged_utime).
inline constexpr const char* kChunkColumns =
    "x, y, z, point_count, min_x, min_y, min_z, max_x, max_y, max_z, last_touched_frame";
inline constexpr const char* kPoseColumns =
    "frame_id, utime, T_world_cam, registered, fitness, rmse_m, correspondences, checksum";
inline constexpr const char* kCheckpointColumns =
    "id, utime, reason, last_frame_id, frames_fused, point_count, chunk_count, T_world_cam, "
    "checksum";
// Of a keyframe up to its images.
inline constexpr const char* kKeyframeColumns =
    "frame_id, utime, sensor_serial, width, height, fx, fy, cx, cy, T_world_cam, checksum";

// The frames the last checkpoint holds, as an SQL condition on a `frame_id` column: every frame up
// to its last_frame_id (none before the first checkpoint). Readers show only these poses and
// keyframes; a writer reopening the file deletes the others.
inline const std::string kCommittedFrames =
    "frame_id <= COALESCE((SELECT last_frame_id FROM checkpoints ORDER BY id DESC LIMIT 1), 0)";

// "SELECT <chunk columns>, <checkpoint id>, <last> FROM <table>": the committed chunks, or the
// staged ones (checkpoint id 0). `last` is the blob or an expression on it, e.g. length(data).
std::string select_chunks(bool staged, const char* last);

// A chunk row's fields read with select_chunks(), except blob_bytes.
ChunkInfo chunk_info_of(const sql::Row& row);

Eigen::AlignedBox3f bounds_of(const PointArrays& a);

// The values of a pose row that its checksum covers besides the pose blob.
PoseFields pose_fields(const PoseRecord& p);

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
// The columns every row of a fused frame starts with (poses, frame_log): frame_id, utime, the pose
// blob (left to the caller, who checks the row's checksum first), registered, fitness, rmse_m,
// correspondences. The frame id's range is the caller's to check.
void read_pose_columns(const sql::Row& row, PoseRecord* p);
// Pinhole intrinsics from six columns starting at `first`: width, height, fx, fy, cx, cy.
CameraIntrinsics read_intrinsics_columns(const sql::Row& row, int first);

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
  Status write_chunk_row(bool staged, const ChunkKey& key, const Chunk& chunk, int64_t last_column);
  Status write_chunk_row(bool staged, const EncodedChunk& chunk, int64_t last_column);
  // Inside a checkpoint: deletes the staged copy of `key` unless a frame after the checkpoint's
  // touched it, and with `committed` the checkpointed row too.
  Status delete_chunk_rows(const ChunkKey& key, bool committed);
  // Reads a row of select_chunks(staged, "data") and decodes its blob into `out`.
  Status decode_chunk_row(const sql::Row& row, bool staged, StoredChunk* out);
  // The first columns of a keyframe row (kKeyframeColumns): everything but the images, the
  // intrinsics valid, the checksum checked (`*unchecked` when the row has none) and the pose
  // decoded.
  Status keyframe_head_of(const sql::Row& row, Keyframe* out, bool* unchecked = nullptr);
  // A row of kCheckpointColumns, its checksum checked.
  Result<CheckpointRecord> checkpoint_of(const sql::Row& row);
  // A row of kPoseColumns: decoded and, when it has one, its checksum checked. `*checked` says
  // whether it had one.
  Result<PoseRecord> pose_of(const sql::Row& row, bool* checked = nullptr);

  // scan_store_open.cpp
  Status open_existing();
  Status create_new();
  Status lock_for_writing();
  Status recover();
};

}  // namespace depthfuse::store
