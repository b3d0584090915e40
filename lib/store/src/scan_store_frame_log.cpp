// The frame redo log of a scan file (table frame_log, docs/checkpoint-format.md): appending the
// records of fused frames, reading back those after the last checkpoint in frame order with every
// checksum checked, and dropping them. Records are encoded and appended on the recorder's frame
// log thread (encode_frame_log_record), on its own connection; resume, export and inspect read
// them.
#include "scan_store_internal.hpp"

namespace depthfuse::store {

namespace {

// The records the last checkpoint does not hold, as an SQL condition.
std::string after_checkpoint() { return "NOT (" + kCommittedFrames + ")"; }

}  // namespace

Status encode_frame_log_record(BlobCodec& codec, const PoseRecord& pose, const Frame& frame,
                               FrameLogRecord* out) {
  const std::string ctx = "frame log record of frame " + std::to_string(pose.frame_id);
  if (!frame.intrinsics.valid() || frame.depth.width != frame.intrinsics.width ||
      frame.depth.height != frame.intrinsics.height)
    return invalid_argument(ctx + ": depth size does not match its intrinsics");
  out->pose = pose;
  out->intrinsics = frame.intrinsics;
  DF_RETURN_IF_ERROR(codec.encode_depth(frame.depth, &out->depth).with_context(ctx));
  out->color.clear();
  // Colour that does not match the depth is not what fusion used (it colours points only when the
  // sizes agree): not kept.
  if (!frame.color.empty() && frame.color.width == frame.depth.width &&
      frame.color.height == frame.depth.height)
    DF_RETURN_IF_ERROR(codec.encode_color(frame.color, &out->color).with_context(ctx));
  return Status::ok();
}

Status ScanStore::append_frame_log(const std::vector<FrameLogRecord>& records) {
  Impl& s = *impl_;
  DF_RETURN_IF_ERROR(s.require_writable("append_frame_log"));
  if (records.empty()) return Status::ok();
  const std::string ctx = "appending " + std::to_string(records.size()) + " frame log records";
  // A frame reported logged must survive a power cut, as a checkpoint does.
  const bool own = !s.in_checkpoint;
  if (own) DF_RETURN_IF_ERROR(s.set_synchronous("FULL"));
  const Status st = s.in_transaction(ctx, [&]() -> Status {
    auto ins = s.db.prepare(std::string("INSERT OR REPLACE INTO frame_log (") + kFrameLogColumns +
                                ") VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?);",
                            ctx);
    if (!ins) return ins.status();
    for (const FrameLogRecord& r : records) {
      const PoseRecord& p = r.pose;
      if (p.frame_id == 0 || p.frame_id == kAllFrames)
        return invalid_argument(s.path + ": frame log record with frame id " + std::to_string(p.frame_id));
      const std::vector<uint8_t> pose = encode_pose(p.T_world_cam);
      const CameraIntrinsics& K = r.intrinsics;
      ins->bind(param(FrameLogCol::kFrameId), p.frame_id).bind(param(FrameLogCol::kUtime), p.utime);
      ins->bind_blob(param(FrameLogCol::kPose), pose);
      ins->bind(param(FrameLogCol::kRegistered), p.registered ? 1 : 0);
      ins->bind(param(FrameLogCol::kFitness), p.fitness).bind(param(FrameLogCol::kRmse), p.rmse_m);
      ins->bind(param(FrameLogCol::kCorrespondences), p.correspondences);
      bind_intrinsics(*ins, param(FrameLogCol::kWidth), K);
      ins->bind(param(FrameLogCol::kChecksum),
                frame_log_row_checksum(p, pose.data(), pose.size(), K, r.depth.data(), r.depth.size(),
                                       r.color.data(), r.color.size()));
      ins->bind_blob(param(FrameLogCol::kDepth), r.depth);
      if (r.color.empty()) ins->bind_null(param(FrameLogCol::kColor));
      else ins->bind_blob(param(FrameLogCol::kColor), r.color);
      DF_RETURN_IF_ERROR(ins->run("logging frame " + std::to_string(p.frame_id)));
    }
    return Status::ok();
  });
  if (own) (void)s.set_synchronous("NORMAL");
  return st;
}

Result<FrameLogSummary> ScanStore::frame_log_summary() {
  Impl& s = *impl_;
  FrameLogSummary out;
  auto st = s.db.prepare("SELECT COUNT(*), COALESCE(MIN(frame_id), 0), COALESCE(MAX(frame_id), 0), "
                         "COALESCE(SUM(length(depth) + COALESCE(length(color), 0)), 0) FROM frame_log "
                         "WHERE " + after_checkpoint() + ";",
                         "summing up the frame log");
  if (!st) return st.status();
  auto row = st->step();
  if (!row) return row.status();
  out.count = static_cast<size_t>(st->row().int64(0));
  out.first_frame_id = static_cast<uint32_t>(st->row().int64(1));
  out.last_frame_id = static_cast<uint32_t>(st->row().int64(2));
  out.bytes = static_cast<uint64_t>(st->row().int64(3));
  auto stale = s.db.query_int("SELECT COUNT(*) FROM frame_log WHERE " + kCommittedFrames + ";",
                              "counting covered frame log records");
  if (!stale) return stale.status();
  out.stale = static_cast<size_t>(*stale);
  return out;
}

Status ScanStore::for_each_logged_frame(const std::function<Status(LoggedFrame&)>& fn,
                                        uint32_t after_frame_id, size_t limit) {
  Impl& s = *impl_;
  auto st = s.db.prepare(std::string("SELECT ") + kFrameLogColumns + " FROM frame_log WHERE " +
                             after_checkpoint() + " AND frame_id > ? ORDER BY frame_id" +
                             (limit > 0 ? " LIMIT " + std::to_string(limit) : std::string()) + ";",
                         "reading the frame log");
  if (!st) return st.status();
  st->bind(1, after_frame_id);
  LoggedFrame f;
  for (const sql::Row& row : st->rows()) {
    const int64_t frame_id = row.int64(FrameLogCol::kFrameId);
    const std::string what = s.path + ": frame log record of frame " + std::to_string(frame_id);
    if (frame_id < 1 || frame_id >= kAllFrames) return corrupt(what + ": the frame id is out of range");
    PoseRecord& p = f.pose;
    read_pose_columns(row, &p);
    CameraIntrinsics& K = f.frame.intrinsics;
    K = read_intrinsics_columns(row, FrameLogCol::kWidth);
    const void* pose = row.blob(FrameLogCol::kPose);
    const size_t pose_size = row.blob_size(FrameLogCol::kPose);
    const void* depth = row.blob(FrameLogCol::kDepth);
    const size_t depth_size = row.blob_size(FrameLogCol::kDepth);
    const bool has_color = !row.is_null(FrameLogCol::kColor);
    const void* color = has_color ? row.blob(FrameLogCol::kColor) : nullptr;
    const size_t color_size = has_color ? row.blob_size(FrameLogCol::kColor) : 0;
    DF_RETURN_IF_ERROR(check_row_checksum(
        row, FrameLogCol::kChecksum,
        frame_log_row_checksum(p, pose, pose_size, K, depth, depth_size, color, color_size), what));
    DF_RETURN_IF_ERROR(decode_pose(pose, pose_size, what + " pose", &p.T_world_cam));
    if (!K.valid()) return corrupt(what + ": invalid intrinsics");
    DF_RETURN_IF_ERROR(s.codec.decode_depth(depth, depth_size, what + " depth", &f.frame.depth));
    if (f.frame.depth.width != K.width || f.frame.depth.height != K.height)
      return corrupt(what + ": depth size disagrees with its intrinsics");
    f.frame.color = ColorImage{};
    if (has_color) {
      DF_RETURN_IF_ERROR(s.codec.decode_color(color, color_size, what + " colour", &f.frame.color));
      if (f.frame.color.width != K.width || f.frame.color.height != K.height)
        return corrupt(what + ": colour and depth sizes differ");
    }
    f.frame.utime = p.utime;
    f.frame.sequence = p.frame_id;
    f.frame.T_world_cam_hint.reset();
    DF_RETURN_IF_ERROR(fn(f));
  }
  return st->status();
}

Status ScanStore::discard_frame_log_from(uint32_t frame_id) {
  DF_RETURN_IF_ERROR(impl_->require_writable("discard_frame_log_from"));
  return impl_->in_transaction("discarding frame log records", [&]() -> Status {
    auto st = impl_->db.prepare("DELETE FROM frame_log WHERE frame_id >= ?;", "discarding frame log records");
    if (!st) return st.status();
    st->bind(1, frame_id);
    return st->run();
  });
}

}  // namespace depthfuse::store
