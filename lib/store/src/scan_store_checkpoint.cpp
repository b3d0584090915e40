// Writing a scan file: checkpoints (begin, write chunks and poses, commit with a full sync or roll
// back whole), keyframes, the metadata and configuration, the pager's staged chunks, and returning
// freed pages. Runs on the thread that owns the connection: the fusion daemon's worker thread
// (through ScanRecorder and MapPager) or the recorder's checkpoint writer thread, each on its own,
// or the CLI's main thread for `depthfuse refine` and `inspect --upgrade`.
#include <cstdio>

#include "depthfuse/base/clock.hpp"
#include "scan_store_internal.hpp"

namespace depthfuse::store {

namespace {

using MetaRows = std::vector<std::pair<std::string, std::string>>;

// The daemon's frame counters as meta rows, from the scan's metadata or a checkpoint (the same
// fields in both): written by set_metadata and by every checkpoint.
template <typename Counts>
void append_frame_counts(const Counts& c, MetaRows* rows) {
  rows->insert(rows->end(), {{"frames_received", std::to_string(c.frames_received)},
                             {"frames_fused", std::to_string(c.frames_fused)},
                             {"frames_tracked_only", std::to_string(c.frames_tracked_only)},
                             {"frames_lost", std::to_string(c.frames_lost)},
                             {"frames_dropped", std::to_string(c.frames_dropped)}});
}

std::string format_double(double v) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.17g", v);
  return buf;
}

}  // namespace

Status ScanStore::set_metadata(const ScanMetadata& m) {
  DF_RETURN_IF_ERROR(impl_->require_writable("set_metadata"));
  MetaRows kv = {
      {"scan_id", m.scan_id},
      {"created_utime", std::to_string(m.created_utime)},
      {"sensor_serial", m.sensor_serial},
      {"method", m.method},
      {"chunk_size_m", format_double(m.chunk_size_m)},
      {"software_version", m.software_version},
  };
  append_frame_counts(m, &kv);
  return impl_->in_transaction("writing metadata", [&] { return impl_->set_meta(kv); });
}

Status ScanStore::set_config(const std::string& toml_text, const std::string& source_path) {
  DF_RETURN_IF_ERROR(impl_->require_writable("set_config"));
  return impl_->in_transaction("writing the configuration", [&] {
    return impl_->set_meta({{"config_toml", toml_text}, {"config_source", source_path}});
  });
}

Status ScanStore::begin_checkpoint(uint32_t up_to_frame) {
  Impl& s = *impl_;
  DF_RETURN_IF_ERROR(s.require_writable("begin_checkpoint"));
  if (s.in_checkpoint) return invalid_argument(s.path + ": a checkpoint is already open");
  if (s.read_depth > 0) return invalid_argument(s.path + ": a read snapshot is open");
  // FULL: the commit record is fsynced before COMMIT returns, so a checkpoint that was reported
  // written survives a power cut.
  DF_RETURN_IF_ERROR(s.set_synchronous("FULL"));
  DF_RETURN_IF_ERROR(s.db.exec("BEGIN IMMEDIATE;", "beginning a checkpoint"));
  auto id = s.db.query_int("SELECT COALESCE(MAX(id), 0) + 1 FROM checkpoints;",
                           "numbering the checkpoint");
  if (!id) {
    s.db.rollback("rolling back");
    return id.status();
  }
  s.checkpoint_id = *id;
  s.checkpoint_up_to_frame = up_to_frame;
  s.in_checkpoint = true;
  return Status::ok();
}

bool ScanStore::in_checkpoint() const { return impl_->in_checkpoint; }

void ScanStore::rollback_checkpoint() {
  Impl& s = *impl_;
  if (!s.in_checkpoint) return;
  s.in_checkpoint = false;
  s.db.rollback("rolling back");
  (void)s.set_synchronous("NORMAL");
}

Status ScanStore::write_chunk(const ChunkKey& key, const Chunk& chunk) {
  Impl& s = *impl_;
  if (!s.in_checkpoint) return invalid_argument(s.path + ": write_chunk outside a checkpoint");
  DF_RETURN_IF_ERROR(encode_chunk(s.codec, key, chunk, &s.encoded).with_context(s.path));
  return write_chunk(s.encoded);
}

Status ScanStore::write_chunk(const EncodedChunk& chunk) {
  Impl& s = *impl_;
  if (!s.in_checkpoint) return invalid_argument(s.path + ": write_chunk outside a checkpoint");
  // An empty chunk has no row.
  DF_RETURN_IF_ERROR(s.delete_chunk_rows(chunk.key, /*committed=*/chunk.point_count == 0));
  if (chunk.point_count == 0) return Status::ok();
  return s.write_chunk_row(ChunkTable::kChunks, chunk, s.checkpoint_id);
}

Status ScanStore::delete_chunk(const ChunkKey& key) {
  Impl& s = *impl_;
  if (!s.in_checkpoint) return invalid_argument(s.path + ": delete_chunk outside a checkpoint");
  return s.delete_chunk_rows(key, /*committed=*/true);
}

Status ScanStore::delete_all_chunks() {
  Impl& s = *impl_;
  if (!s.in_checkpoint) return invalid_argument(s.path + ": delete_all_chunks outside a checkpoint");
  DF_RETURN_IF_ERROR(s.db.exec("DELETE FROM chunk_staging;", "deleting chunks"));
  DF_RETURN_IF_ERROR(s.db.exec("DELETE FROM chunk_pending;", "deleting pending points"));
  return s.db.exec("DELETE FROM chunks;", "deleting chunks");
}

Status ScanStore::write_pending(const std::vector<EncodedChunk>& pending) {
  Impl& s = *impl_;
  if (!s.in_checkpoint) return invalid_argument(s.path + ": write_pending outside a checkpoint");
  // Rewritten whole: the points come and go with the deformation's sweep, a few chunks' worth.
  DF_RETURN_IF_ERROR(s.db.exec("DELETE FROM chunk_pending;", "replacing the pending points"));
  for (const EncodedChunk& p : pending)
    if (p.point_count > 0)
      DF_RETURN_IF_ERROR(s.write_chunk_row(ChunkTable::kPending, p, s.checkpoint_id));
  return Status::ok();
}

Status ScanStore::write_pending(const std::vector<PendingPoints>& pending) {
  Impl& s = *impl_;
  std::vector<EncodedChunk> encoded(pending.size());
  for (size_t i = 0; i < pending.size(); ++i)
    DF_RETURN_IF_ERROR(encode_pending(s.codec, pending[i], &encoded[i]).with_context(s.path));
  return write_pending(encoded);
}

Status ScanStore::write_pose(const PoseRecord& p) {
  if (p.frame_id == 0 || p.frame_id == kAllFrames)
    return invalid_argument(impl_->path + ": pose with frame id " + std::to_string(p.frame_id));
  DF_RETURN_IF_ERROR(impl_->require_writable("write_pose"));
  return impl_->in_transaction("writing poses", [&] { return impl_->write_pose_row(p, PoseAnchor()); });
}

Status ScanStore::Impl::write_pose_row(const PoseRecord& p, const PoseAnchor& anchor) {
  auto st = db.prepare(std::string("INSERT OR REPLACE INTO poses (") + kPoseColumns +
                           ") VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?);",
                       "writing the pose of frame " + std::to_string(p.frame_id));
  if (!st) return st.status();
  const std::vector<uint8_t> pose = encode_pose(p.T_world_cam);
  st->bind(param(PoseCol::kFrameId), p.frame_id).bind(param(PoseCol::kUtime), p.utime);
  st->bind_blob(param(PoseCol::kPose), pose).bind(param(PoseCol::kRegistered), p.registered ? 1 : 0);
  st->bind(param(PoseCol::kFitness), p.fitness).bind(param(PoseCol::kRmse), p.rmse_m);
  st->bind(param(PoseCol::kCorrespondences), p.correspondences);
  bind_anchor(*st, param(PoseCol::kAnchor), anchor);
  st->bind(param(PoseCol::kChecksum),
           with_anchor(pose_record_checksum(pose_fields(p), pose.data(), pose.size()), anchor));
  return st->run();
}

Status ScanStore::update_keyframe_pose(uint32_t frame_id, const Pose& T_world_cam) {
  DF_RETURN_IF_ERROR(impl_->require_writable("update_keyframe_pose"));
  return impl_->in_transaction("updating the pose of keyframe " + std::to_string(frame_id), [&] {
    return impl_->set_keyframe_pose(frame_id, T_world_cam, PoseAnchor());
  });
}

Status ScanStore::Impl::set_keyframe_pose(uint32_t frame_id, const Pose& T, const PoseAnchor& anchor) {
  const std::string ctx = "updating the pose of keyframe " + std::to_string(frame_id);
  // The checksum covers the values the pose is used with: read them back.
  auto row = db.prepare("SELECT utime, width, height, fx, fy, cx, cy FROM keyframes WHERE frame_id = ?;",
                        ctx);
  if (!row) return row.status();
  row->bind(1, frame_id);
  auto found = row->step();
  if (!found) return found.status();
  if (!*found) return not_found(path + ": no keyframe " + std::to_string(frame_id));
  const sql::Row r = row->row();
  const CameraIntrinsics K = read_intrinsics_columns(r, 1);
  const std::vector<uint8_t> pose = encode_pose(T);
  const uint32_t checksum =
      with_anchor(keyframe_row_checksum(frame_id, r.int64(0), K, pose.data(), pose.size()), anchor);
  auto st = db.prepare("UPDATE keyframes SET T_world_cam = ?, graph_keyframe = ?, checksum = ? "
                       "WHERE frame_id = ?;",
                       ctx);
  if (!st) return st.status();
  st->bind_blob(1, pose);
  bind_anchor(*st, 2, anchor);
  st->bind(3, checksum).bind(4, frame_id);
  return st->run();
}

Status ScanStore::write_keyframe(const Keyframe& k) {
  DF_RETURN_IF_ERROR(impl_->require_writable("write_keyframe"));
  const std::string ctx = "writing keyframe " + std::to_string(k.frame_id);
  if (!k.intrinsics.valid() || k.depth.width != k.intrinsics.width ||
      k.depth.height != k.intrinsics.height)
    return invalid_argument(impl_->path + ": " + ctx + ": depth size does not match its intrinsics");
  std::vector<uint8_t> depth, color;
  DF_RETURN_IF_ERROR(impl_->codec.encode_depth(k.depth, &depth).with_context(ctx));
  if (!k.color.empty()) DF_RETURN_IF_ERROR(impl_->codec.encode_color(k.color, &color).with_context(ctx));
  const std::vector<uint8_t> pose = encode_pose(k.T_world_cam);
  return impl_->in_transaction(ctx, [&]() -> Status {
    auto st = impl_->db.prepare(std::string("INSERT OR REPLACE INTO keyframes (") +
                                    kKeyframeColumns +
                                    ", depth, color) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?);",
                                ctx);
    if (!st) return st.status();
    st->bind(param(KeyframeCol::kFrameId), k.frame_id).bind(param(KeyframeCol::kUtime), k.utime);
    st->bind(param(KeyframeCol::kSensorSerial), k.sensor_serial);
    bind_intrinsics(*st, param(KeyframeCol::kWidth), k.intrinsics);
    st->bind_blob(param(KeyframeCol::kPose), pose);
    st->bind_null(param(KeyframeCol::kAnchor));  // anchored by the checkpoint that holds it
    st->bind(param(KeyframeCol::kChecksum),
             keyframe_row_checksum(k.frame_id, k.utime, k.intrinsics, pose.data(), pose.size()));
    st->bind_blob(param(KeyframeCol::kDepth), depth);
    if (color.empty()) st->bind_null(param(KeyframeCol::kColor));
    else st->bind_blob(param(KeyframeCol::kColor), color);
    return st->run();
  });
}

Result<CheckpointRecord> ScanStore::commit_checkpoint(const CheckpointInfo& info) {
  Impl& s = *impl_;
  if (!s.in_checkpoint) return invalid_argument(s.path + ": commit_checkpoint without a checkpoint");
  const std::string ctx = "committing checkpoint " + std::to_string(s.checkpoint_id);
  CheckpointRecord rec;
  rec.id = s.checkpoint_id;
  rec.utime = now_utime();
  rec.reason = info.reason;
  rec.last_frame_id = info.last_frame_id;
  rec.frames_fused = info.frames_fused;
  rec.T_world_cam = info.T_world_cam;
  auto body = [&]() -> Status {
    // Staged chunks (evicted since the last checkpoint) of the checkpoint's frames become part of
    // it; staged empty chunks are deletions. Those a later frame touched stay staged.
    const std::string ours = "last_touched_frame <= " + std::to_string(s.checkpoint_up_to_frame);
    DF_RETURN_IF_ERROR(s.db.exec(
        "DELETE FROM chunks WHERE EXISTS (SELECT 1 FROM chunk_staging AS s WHERE s.x = chunks.x "
        "AND s.y = chunks.y AND s.z = chunks.z AND s.point_count = 0 AND s." + ours + ");",
        ctx));
    DF_RETURN_IF_ERROR(s.db.exec(
        std::string("INSERT OR REPLACE INTO chunks (") + kChunkColumns +
            ", checkpoint_id, data) SELECT " + kChunkColumns + ", " +
            std::to_string(s.checkpoint_id) + ", data FROM chunk_staging WHERE point_count > 0 AND " +
            ours + ";",
        ctx));
    DF_RETURN_IF_ERROR(s.db.exec("DELETE FROM chunk_staging WHERE " + ours + ";", ctx));
    auto counts = s.db.prepare("SELECT COUNT(*), COALESCE(SUM(point_count), 0) FROM chunks;", ctx);
    if (!counts) return counts.status();
    auto row = counts->step();
    if (!row) return row.status();
    rec.chunk_count = static_cast<uint64_t>(counts->row().int64(0));
    rec.point_count = static_cast<uint64_t>(counts->row().int64(1));
    auto ins = s.db.prepare(std::string("INSERT INTO checkpoints (") + kCheckpointColumns +
                                ") VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?);",
                            ctx);
    if (!ins) return ins.status();
    std::vector<uint8_t> pose;
    if (info.T_world_cam) pose = encode_pose(*info.T_world_cam);
    ins->bind(param(CheckpointCol::kId), rec.id).bind(param(CheckpointCol::kUtime), rec.utime);
    ins->bind(param(CheckpointCol::kReason), rec.reason);
    ins->bind(param(CheckpointCol::kLastFrameId), rec.last_frame_id);
    ins->bind(param(CheckpointCol::kFramesFused), static_cast<int64_t>(rec.frames_fused));
    ins->bind(param(CheckpointCol::kPointCount), static_cast<int64_t>(rec.point_count));
    ins->bind(param(CheckpointCol::kChunkCount), static_cast<int64_t>(rec.chunk_count));
    if (pose.empty()) ins->bind_null(param(CheckpointCol::kPose));
    else ins->bind_blob(param(CheckpointCol::kPose), pose);
    ins->bind(param(CheckpointCol::kChecksum), checkpoint_row_checksum(rec, pose.data(), pose.size()));
    DF_RETURN_IF_ERROR(ins->run());
    // The redo log's records of the checkpoint's frames are in the chunks now.
    DF_RETURN_IF_ERROR(s.db.exec("DELETE FROM frame_log WHERE frame_id <= " +
                                     std::to_string(rec.last_frame_id) + ";",
                                 ctx));
    MetaRows frame_counts;
    append_frame_counts(info, &frame_counts);
    DF_RETURN_IF_ERROR(s.set_meta(frame_counts));
    return s.db.exec("COMMIT;", ctx);
  };
  Status st = body();
  s.in_checkpoint = false;
  if (!st) s.db.rollback("rolling back");
  (void)s.set_synchronous("NORMAL");
  if (!st) return st;
  return rec;
}

Status ScanStore::stage_chunks(const std::vector<std::pair<ChunkKey, const Chunk*>>& chunks) {
  Impl& s = *impl_;
  DF_RETURN_IF_ERROR(s.require_writable("stage_chunks"));
  if (s.in_checkpoint)
    return invalid_argument(s.path + ": cannot stage chunks while a checkpoint is open");
  if (chunks.empty()) return Status::ok();
  const int64_t t = now_utime();
  return s.in_transaction("staging evicted chunks", [&]() -> Status {
    for (const auto& [key, chunk] : chunks)
      DF_RETURN_IF_ERROR(s.write_chunk_row(ChunkTable::kStaging, key, *chunk, t));
    return Status::ok();
  });
}

Status ScanStore::compact() {
  Impl& s = *impl_;
  DF_RETURN_IF_ERROR(s.require_writable("compact"));
  if (s.in_checkpoint) return invalid_argument(s.path + ": compact inside a checkpoint");
  return s.db.exec("PRAGMA incremental_vacuum;", "returning free pages");
}

}  // namespace depthfuse::store
