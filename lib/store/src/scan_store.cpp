// ScanStore's shared pieces: the Impl's lifetime, transactions, the meta table's rows, and the
// chunk and checkpoint rows every other unit reads or writes (scan_store_internal.hpp lists the
// units). Runs on the thread that uses the ScanStore: the fusion daemon's worker thread for the
// writer, the CLI's main thread for readers.
#include <unistd.h>

#include <cstdio>

#include "depthfuse/store/blob_codec.hpp"
#include "depthfuse/store/checksum.hpp"

#include "scan_store_internal.hpp"

namespace depthfuse::store {

std::string to_string(const ChunkKey& k) {
  return "(" + std::to_string(k.x) + "," + std::to_string(k.y) + "," + std::to_string(k.z) + ")";
}

Keyframe Keyframe::from_frame(const Frame& frame, uint32_t frame_id, const Pose& T_world_cam,
                              bool keep_color) {
  Keyframe k;
  k.frame_id = frame_id;
  k.utime = frame.utime;
  k.sensor_serial = frame.sensor_serial;
  k.intrinsics = frame.intrinsics;
  k.T_world_cam = T_world_cam;
  k.depth = frame.depth;
  if (keep_color) k.color = frame.color;
  return k;
}

Frame Keyframe::to_frame() const {
  Frame f;
  f.utime = utime;
  f.sequence = frame_id;
  f.sensor_serial = sensor_serial;
  f.intrinsics = intrinsics;
  f.depth = depth;
  f.color = color;
  f.T_world_cam_hint = T_world_cam;
  return f;
}

const char* table_name(ChunkTable table) {
  switch (table) {
    case ChunkTable::kChunks: return "chunks";
    case ChunkTable::kStaging: return "chunk_staging";
    case ChunkTable::kPending: return "chunk_pending";
  }
  return "";
}

std::string select_chunks(ChunkTable table, const char* last) {
  return std::string("SELECT ") + kChunkColumns + ", " +
         (table == ChunkTable::kStaging ? "0" : "checkpoint_id") + ", " + last + " FROM " +
         table_name(table);
}

ChunkInfo chunk_info_of(const sql::Row& row) {
  ChunkInfo info;
  info.key = {static_cast<int32_t>(row.int64(ChunkCol::kX)), static_cast<int32_t>(row.int64(ChunkCol::kY)),
              static_cast<int32_t>(row.int64(ChunkCol::kZ))};
  info.point_count = static_cast<uint32_t>(row.int64(ChunkCol::kPointCount));
  info.bounds_m.setEmpty();
  if (!row.is_null(ChunkCol::kMinX)) {
    for (int i = 0; i < 3; ++i) {
      info.bounds_m.min()[i] = static_cast<float>(row.real(ChunkCol::kMinX + i));
      info.bounds_m.max()[i] = static_cast<float>(row.real(ChunkCol::kMaxX + i));
    }
  }
  info.last_touched_frame = static_cast<uint32_t>(row.int64(ChunkCol::kLastTouchedFrame));
  info.version = static_cast<uint32_t>(row.int64(ChunkCol::kVersion));
  info.checkpoint_id = row.int64(ChunkCol::kCheckpointId);
  info.checksummed = !row.is_null(ChunkCol::kChecksum);
  return info;
}

Eigen::AlignedBox3f bounds_of(const PointArrays& a) {
  Eigen::AlignedBox3f box;
  for (size_t i = 0; i < a.size(); ++i) box.extend(a.position_m[i]);
  return box;
}

ScanStore::Impl::~Impl() {
  if (in_checkpoint) db.rollback("rolling back");
  db.close();
  // After SQLite closed its descriptors: closing ours earlier would drop SQLite's POSIX locks.
  if (lock_fd >= 0) ::close(lock_fd);
}

Status ScanStore::Impl::set_synchronous(const char* level) {
  return db.exec(std::string("PRAGMA synchronous = ") + level + ";", "setting synchronous");
}

Status ScanStore::Impl::set_meta(const std::vector<std::pair<std::string, std::string>>& kv) {
  auto st = db.prepare("INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?);", "writing meta");
  if (!st) return st.status();
  for (const auto& [k, v] : kv) {
    st->bind(1, k).bind(2, v);
    DF_RETURN_IF_ERROR(st->run("writing meta '" + k + "'"));
  }
  return Status::ok();
}

Result<std::optional<std::string>> ScanStore::Impl::get_meta(const std::string& key) {
  auto st = db.prepare("SELECT value FROM meta WHERE key = ?;", "reading meta '" + key + "'");
  if (!st) return st.status();
  st->bind(1, key);
  auto found = st->step();
  if (!found) return found.status();
  if (!*found) return std::optional<std::string>();
  return std::optional<std::string>(st->row().text(0));
}

Status encode_chunk(BlobCodec& codec, const ChunkKey& key, const Chunk& chunk, EncodedChunk* out) {
  out->key = key;
  out->point_count = static_cast<uint32_t>(chunk.points().size());
  out->bounds_m = bounds_of(chunk.points());
  out->last_touched_frame = chunk.last_touched_frame;
  out->version = chunk.version;
  return codec.encode_points(chunk.points(), &out->blob).with_context("encoding chunk " + to_string(key));
}

Status encode_pending(BlobCodec& codec, const PendingPoints& pending, EncodedChunk* out) {
  out->key = pending.key;
  out->point_count = static_cast<uint32_t>(pending.points.size());
  out->bounds_m = bounds_of(pending.points);
  out->last_touched_frame = 0;
  out->version = pending.version;
  return codec.encode_points(pending.points, &out->blob)
      .with_context("encoding the points pending for chunk " + to_string(pending.key));
}

Status ScanStore::Impl::write_chunk_row(ChunkTable table, const ChunkKey& key, const Chunk& chunk,
                                        int64_t last_column) {
  DF_RETURN_IF_ERROR(encode_chunk(codec, key, chunk, &encoded).with_context(path));
  return write_chunk_row(table, encoded, last_column);
}

Status ScanStore::Impl::write_chunk_row(ChunkTable table, const EncodedChunk& chunk,
                                        int64_t last_column) {
  const ChunkKey& key = chunk.key;
  const Eigen::AlignedBox3f& box = chunk.bounds_m;
  const std::string sql =
      std::string("INSERT OR REPLACE INTO ") + table_name(table) + " (" + kChunkColumns +
      (table == ChunkTable::kStaging ? ", staged_utime" : ", checkpoint_id") +
      ", data) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?);";
  auto st = db.prepare(sql, "writing chunk " + to_string(key));
  if (!st) return st.status();
  st->bind(param(ChunkCol::kX), key.x).bind(param(ChunkCol::kY), key.y).bind(param(ChunkCol::kZ), key.z);
  st->bind(param(ChunkCol::kPointCount), static_cast<int64_t>(chunk.point_count));
  for (int i = 0; i < 3; ++i) {
    if (box.isEmpty()) {
      st->bind_null(param(ChunkCol::kMinX + i)).bind_null(param(ChunkCol::kMaxX + i));
    } else {
      st->bind(param(ChunkCol::kMinX + i), static_cast<double>(box.min()[i]));
      st->bind(param(ChunkCol::kMaxX + i), static_cast<double>(box.max()[i]));
    }
  }
  st->bind(param(ChunkCol::kLastTouchedFrame), chunk.last_touched_frame);
  st->bind(param(ChunkCol::kVersion), chunk.version);
  st->bind(param(ChunkCol::kChecksum),
           chunk_row_checksum(key, chunk.point_count, chunk.last_touched_frame, chunk.version));
  st->bind(param(ChunkCol::kCheckpointId), last_column);
  st->bind_blob(param(ChunkCol::kData), chunk.blob);
  return st->run();
}

Status ScanStore::Impl::delete_chunk_rows(const ChunkKey& key, bool committed) {
  auto run = [&](const std::string& sql, bool up_to_frame) -> Status {
    auto st = db.prepare(sql, "deleting chunk " + to_string(key));
    if (!st) return st.status();
    st->bind(1, key.x).bind(2, key.y).bind(3, key.z);
    if (up_to_frame) st->bind(4, static_cast<int64_t>(checkpoint_up_to_frame));
    return st->run();
  };
  const std::string where = " WHERE x = ? AND y = ? AND z = ?";
  DF_RETURN_IF_ERROR(run("DELETE FROM chunk_staging" + where + " AND last_touched_frame <= ?;", true));
  if (!committed) return Status::ok();
  return run("DELETE FROM chunks" + where + ";", false);
}

Status ScanStore::Impl::decode_chunk_row(const sql::Row& row, ChunkTable table, StoredChunk* out) {
  ChunkInfo& info = out->info;
  info = chunk_info_of(row);
  info.blob_bytes = row.blob_size(ChunkCol::kData);
  const std::string what =
      path + ": " +
      (table == ChunkTable::kPending
           ? "points pending for chunk " + to_string(info.key) + " at version " +
                 std::to_string(info.version)
           : (table == ChunkTable::kStaging ? "staged chunk " : "chunk ") + to_string(info.key));
  // Pending rows came with schema 8, every one with its checksum.
  if (table == ChunkTable::kPending && row.is_null(ChunkCol::kChecksum))
    return corrupt(what + ": no checksum (every such row has one): the row was altered or damaged");
  DF_RETURN_IF_ERROR(check_row_checksum(
      row, ChunkCol::kChecksum,
      chunk_row_checksum(info.key, info.point_count, info.last_touched_frame, info.version), what));
  DF_RETURN_IF_ERROR(codec.decode_points(row.blob(ChunkCol::kData), row.blob_size(ChunkCol::kData),
                                         what, &out->chunk.points_for_write()));
  if (out->chunk.points().size() != info.point_count)
    return corrupt(what + ": holds " + std::to_string(out->chunk.points().size()) +
                   " points, its row says " + std::to_string(info.point_count));
  out->chunk.last_touched_frame = out->chunk.last_seen_frame = info.last_touched_frame;
  out->chunk.version = info.version;
  out->chunk.dirty = false;
  return Status::ok();
}

uint32_t chunk_row_checksum(const ChunkKey& key, uint32_t point_count, uint32_t last_touched_frame,
                            uint32_t version) {
  return RowCrc()
      .add(key.x).add(key.y).add(key.z)
      .add(point_count).add(last_touched_frame).add(version)
      .value();
}

uint32_t keyframe_row_checksum(uint32_t frame_id, int64_t utime, const CameraIntrinsics& K,
                               const void* pose_blob, size_t pose_size) {
  return RowCrc()
      .add(frame_id).add(utime)
      .add(static_cast<uint32_t>(K.width)).add(static_cast<uint32_t>(K.height))
      .add(K.fx).add(K.fy).add(K.cx).add(K.cy)
      .bytes(pose_blob, pose_size)
      .value();
}

uint32_t frame_log_row_checksum(const PoseRecord& p, const void* pose_blob, size_t pose_size,
                                const CameraIntrinsics& K, const void* depth, size_t depth_size,
                                const void* color, size_t color_size) {
  return RowCrc()
      .add(pose_record_checksum(pose_fields(p), pose_blob, pose_size))
      .add(static_cast<uint32_t>(K.width)).add(static_cast<uint32_t>(K.height))
      .add(K.fx).add(K.fy).add(K.cx).add(K.cy)
      .add(static_cast<uint32_t>(depth_size)).bytes(depth, depth_size)
      .add(static_cast<uint32_t>(color_size)).bytes(color, color_size)
      .value();
}

uint32_t checkpoint_row_checksum(const CheckpointRecord& r, const void* pose_blob, size_t pose_size) {
  return RowCrc()
      .add(r.id).add(r.utime).add(r.last_frame_id)
      .add(r.frames_fused).add(r.point_count).add(r.chunk_count)
      .add(static_cast<uint32_t>(r.reason.size())).bytes(r.reason.data(), r.reason.size())
      .bytes(pose_blob, pose_size)
      .value();
}

Status checksum_mismatch(const std::string& what, uint32_t stored, uint32_t computed) {
  char buf[80];
  std::snprintf(buf, sizeof(buf), ": checksum mismatch (stored 0x%08x, computed 0x%08x)", stored,
                computed);
  return corrupt(what + buf);
}

Status check_row_checksum(const sql::Row& row, int column, uint32_t computed, const std::string& what,
                          bool* unchecked) {
  if (unchecked) *unchecked = row.is_null(column);
  if (row.is_null(column)) return Status::ok();
  const auto stored = static_cast<uint32_t>(row.int64(column));
  if (stored != computed) return checksum_mismatch(what, stored, computed);
  return Status::ok();
}

Result<PoseAnchor> read_anchor(const sql::Row& row, int column, const std::string& what) {
  if (row.is_null(column)) return PoseAnchor();
  const int64_t k = row.int64(column);
  if (k < 0 || k > UINT32_MAX)
    return corrupt(what + ": pose graph keyframe " + std::to_string(k) + " is out of range");
  return PoseAnchor(static_cast<uint32_t>(k));
}

void bind_anchor(sql::Statement& st, int param, const PoseAnchor& anchor) {
  if (anchor) st.bind(param, *anchor);
  else st.bind_null(param);
}

uint32_t with_anchor(uint32_t checksum, const PoseAnchor& anchor) {
  if (!anchor) return checksum;
  return RowCrc().add(checksum).add(*anchor).value();
}

Status ScanStore::Impl::resolve_anchor(const PoseAnchor& anchor, const std::vector<Pose>& T_world_kf,
                                       Pose* T, const std::string& what) const {
  if (!anchor) return Status::ok();
  if (*anchor >= T_world_kf.size())
    return corrupt(what + ": relative to pose graph keyframe " + std::to_string(*anchor) +
                   ", which the graph (" + std::to_string(T_world_kf.size()) +
                   " keyframes) does not have");
  *T = T_world_kf[*anchor] * *T;
  return Status::ok();
}

Status ScanStore::Impl::keyframe_head_of(const sql::Row& row, const std::vector<Pose>& T_world_kf,
                                         Keyframe* k, bool* unchecked) {
  const int64_t frame_id = row.int64(KeyframeCol::kFrameId);
  const std::string what = path + ": keyframe " + std::to_string(frame_id);
  if (frame_id < 1 || frame_id >= kAllFrames) return corrupt(what + ": the frame id is out of range");
  k->frame_id = static_cast<uint32_t>(frame_id);
  k->utime = row.int64(KeyframeCol::kUtime);
  k->sensor_serial = row.text(KeyframeCol::kSensorSerial);
  k->intrinsics = read_intrinsics_columns(row, KeyframeCol::kWidth);
  if (!k->intrinsics.valid()) return corrupt(what + ": invalid intrinsics");
  auto anchor = read_anchor(row, KeyframeCol::kAnchor, what);
  if (!anchor) return anchor.status();
  const void* pose = row.blob(KeyframeCol::kPose);
  const size_t pose_size = row.blob_size(KeyframeCol::kPose);
  DF_RETURN_IF_ERROR(check_row_checksum(
      row, KeyframeCol::kChecksum,
      with_anchor(keyframe_row_checksum(k->frame_id, k->utime, k->intrinsics, pose, pose_size),
                  *anchor),
      what, unchecked));
  DF_RETURN_IF_ERROR(decode_pose(pose, pose_size, what + " pose", &k->T_world_cam));
  return resolve_anchor(*anchor, T_world_kf, &k->T_world_cam, what + " pose");
}

Result<CheckpointRecord> ScanStore::Impl::checkpoint_of(const sql::Row& row) {
  CheckpointRecord r;
  r.id = row.int64(CheckpointCol::kId);
  r.utime = row.int64(CheckpointCol::kUtime);
  r.reason = row.text(CheckpointCol::kReason);
  const std::string what = path + ": checkpoint " + std::to_string(r.id);
  // A resume continues at last_frame_id + 1, which must be a frame id too.
  const int64_t last_frame_id = row.int64(CheckpointCol::kLastFrameId);
  if (last_frame_id < 0 || last_frame_id >= kAllFrames - 1)
    return corrupt(what + ": last frame id " + std::to_string(last_frame_id) + " is out of range");
  for (const int col : {CheckpointCol::kFramesFused, CheckpointCol::kPointCount, CheckpointCol::kChunkCount})
    if (row.int64(col) < 0) return corrupt(what + ": a negative count (" + std::to_string(row.int64(col)) + ")");
  r.last_frame_id = static_cast<uint32_t>(last_frame_id);
  r.frames_fused = static_cast<uint64_t>(row.int64(CheckpointCol::kFramesFused));
  r.point_count = static_cast<uint64_t>(row.int64(CheckpointCol::kPointCount));
  r.chunk_count = static_cast<uint64_t>(row.int64(CheckpointCol::kChunkCount));
  const void* pose = row.blob(CheckpointCol::kPose);
  const size_t pose_size = row.blob_size(CheckpointCol::kPose);
  DF_RETURN_IF_ERROR(check_row_checksum(row, CheckpointCol::kChecksum,
                                        checkpoint_row_checksum(r, pose, pose_size), what));
  if (!row.is_null(CheckpointCol::kPose)) {
    Pose T;
    DF_RETURN_IF_ERROR(decode_pose(pose, pose_size, what, &T));
    r.T_world_cam = T;
  }
  return r;
}

PoseFields pose_fields(const PoseRecord& p) {
  PoseFields f;
  f.frame_id = p.frame_id;
  f.utime = p.utime;
  f.registered = p.registered;
  f.fitness = p.fitness;
  f.rmse_m = p.rmse_m;
  f.correspondences = p.correspondences;
  return f;
}

void read_pose_columns(const sql::Row& row, PoseRecord* p) {
  p->frame_id = static_cast<uint32_t>(row.int64(PoseCol::kFrameId));
  p->utime = row.int64(PoseCol::kUtime);
  p->registered = row.int64(PoseCol::kRegistered) != 0;
  p->fitness = row.real(PoseCol::kFitness);
  p->rmse_m = row.real(PoseCol::kRmse);
  p->correspondences = static_cast<uint32_t>(row.int64(PoseCol::kCorrespondences));
}

CameraIntrinsics read_intrinsics_columns(const sql::Row& row, int first) {
  CameraIntrinsics K;
  K.width = static_cast<int>(row.int64(first));
  K.height = static_cast<int>(row.int64(first + 1));
  K.fx = row.real(first + 2);
  K.fy = row.real(first + 3);
  K.cx = row.real(first + 4);
  K.cy = row.real(first + 5);
  return K;
}

void bind_intrinsics(sql::Statement& st, int first, const CameraIntrinsics& K) {
  st.bind(first, K.width).bind(first + 1, K.height).bind(first + 2, K.fx).bind(first + 3, K.fy);
  st.bind(first + 4, K.cx).bind(first + 5, K.cy);
}

Result<PoseRecord> ScanStore::Impl::pose_of(const sql::Row& row, const std::vector<Pose>& T_world_kf,
                                            bool* checked) {
  PoseRecord p;
  const int64_t frame_id = row.int64(PoseCol::kFrameId);
  const std::string what = path + ": pose of frame " + std::to_string(frame_id);
  if (frame_id < 1 || frame_id >= kAllFrames)
    return corrupt(what + ": the frame id is out of range (1 to " + std::to_string(kAllFrames - 1) + ")");
  read_pose_columns(row, &p);
  auto anchor = read_anchor(row, PoseCol::kAnchor, what);
  if (!anchor) return anchor.status();
  bool unchecked = false;
  const void* pose = row.blob(PoseCol::kPose);
  const size_t pose_size = row.blob_size(PoseCol::kPose);
  // `checked` is set before a mismatch returns: a row with a wrong checksum still has one.
  const Status sum = check_row_checksum(
      row, PoseCol::kChecksum,
      with_anchor(pose_record_checksum(pose_fields(p), pose, pose_size), *anchor), what, &unchecked);
  if (checked) *checked = !unchecked;
  DF_RETURN_IF_ERROR(sum);
  DF_RETURN_IF_ERROR(decode_pose(pose, pose_size, what, &p.T_world_cam));
  DF_RETURN_IF_ERROR(resolve_anchor(*anchor, T_world_kf, &p.T_world_cam, what));
  return p;
}

ScanStore::ScanStore(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
ScanStore::~ScanStore() = default;

const std::string& ScanStore::path() const { return impl_->path; }
bool ScanStore::read_only() const { return !impl_->writable(); }
int ScanStore::schema_version() const { return impl_->schema_version; }
const OpenReport& ScanStore::open_report() const { return impl_->report; }

}  // namespace depthfuse::store
