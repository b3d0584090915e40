// Reading a scan file: read snapshots, the metadata and configuration, chunks (one at a time,
// optionally within a box), the poses and keyframes of the last checkpoint, the checkpoints, a
// summary, and a compact copy. Readers run in the CLI (depthfuse export, inspect, refine) while the
// daemon writes, each process with its own connection; the fusion daemon's worker thread reads too
// (the pager loads chunks, a resume reads the last checkpoint, the final export).
#include <sys/stat.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <type_traits>

#include "scan_store_internal.hpp"

namespace depthfuse::store {

namespace {

uint64_t file_size(const std::string& path) {
  struct stat st {};
  return ::stat(path.c_str(), &st) == 0 ? static_cast<uint64_t>(st.st_size) : 0;
}

}  // namespace

Status ScanStore::begin_read() {
  Impl& s = *impl_;
  if (s.in_checkpoint) return invalid_argument(s.path + ": begin_read inside a checkpoint");
  if (s.read_depth++ > 0) return Status::ok();
  Status st = s.db.exec("BEGIN;", "beginning a read");
  // The snapshot starts with the first read.
  if (st) {
    auto n = s.db.query_int("SELECT COUNT(*) FROM checkpoints;", "beginning a read");
    if (!n) st = n.status();
  }
  if (!st) {
    s.db.rollback("ending a read");
    s.read_depth = 0;
  }
  return st;
}

void ScanStore::end_read() {
  Impl& s = *impl_;
  if (s.read_depth == 0) return;
  if (--s.read_depth == 0 && s.db.in_transaction()) (void)s.db.exec("COMMIT;", "ending a read");
}

Result<ScanMetadata> ScanStore::metadata() {
  auto st = impl_->db.prepare("SELECT key, value FROM meta;", "reading metadata");
  if (!st) return st.status();
  ScanMetadata m;
  for (const sql::Row& row : st->rows()) {
    const std::string k = row.text(0), v = row.text(1);
    auto as_u64 = [&](uint64_t* out) { *out = std::strtoull(v.c_str(), nullptr, 10); };
    if (k == "scan_id") m.scan_id = v;
    else if (k == "created_utime") m.created_utime = std::strtoll(v.c_str(), nullptr, 10);
    else if (k == "sensor_serial") m.sensor_serial = v;
    else if (k == "method") m.method = v;
    else if (k == "chunk_size_m") {
      m.chunk_size_m = std::strtod(v.c_str(), nullptr);
      if (!(m.chunk_size_m > 0.0) || !std::isfinite(m.chunk_size_m))
        return corrupt(impl_->path + ": meta chunk_size_m '" + v + "' is not a positive number");
    } else if (k == "software_version") m.software_version = v;
    else if (k == "frames_received") as_u64(&m.frames_received);
    else if (k == "frames_fused") as_u64(&m.frames_fused);
    else if (k == "frames_tracked_only") as_u64(&m.frames_tracked_only);
    else if (k == "frames_lost") as_u64(&m.frames_lost);
    else if (k == "frames_dropped") as_u64(&m.frames_dropped);
  }
  DF_RETURN_IF_ERROR(st->status());
  return m;
}

Result<std::optional<std::string>> ScanStore::config_toml() { return impl_->get_meta("config_toml"); }

Result<StoredChunk> ScanStore::read_chunk(const ChunkKey& key, bool include_staged) {
  Impl& s = *impl_;
  for (const bool staged : {true, false}) {
    if (staged && !include_staged) continue;
    const ChunkTable table = staged ? ChunkTable::kStaging : ChunkTable::kChunks;
    auto st = s.db.prepare(select_chunks(table, "data") + " WHERE x = ? AND y = ? AND z = ?;",
                           "reading chunk " + to_string(key));
    if (!st) return st.status();
    st->bind(1, key.x).bind(2, key.y).bind(3, key.z);
    auto found = st->step();
    if (!found) return found.status();
    if (!*found) continue;
    StoredChunk out;
    DF_RETURN_IF_ERROR(s.decode_chunk_row(st->row(), table, &out));
    return out;
  }
  return not_found(s.path + ": no chunk " + to_string(key));
}

Result<std::vector<ChunkInfo>> ScanStore::list_chunks(bool include_staged) {
  Impl& s = *impl_;
  std::vector<ChunkInfo> out;
  for (const bool staged : {false, true}) {
    if (staged && !include_staged) continue;
    auto rows = s.db.collect<ChunkInfo>(
        select_chunks(staged ? ChunkTable::kStaging : ChunkTable::kChunks, "length(data)") +
            " ORDER BY x, y, z;",
        staged ? "listing staged chunks" : "listing chunks",
        [](const sql::Row& row) -> Result<ChunkInfo> {
          ChunkInfo info = chunk_info_of(row);
          info.blob_bytes = static_cast<size_t>(row.int64(ChunkCol::kData));
          return info;
        });
    if (!rows) return rows.status();
    out.insert(out.end(), rows->begin(), rows->end());
  }
  return out;
}

Result<std::vector<PendingPoints>> ScanStore::read_pending() {
  Impl& s = *impl_;
  auto st = s.db.prepare(select_chunks(ChunkTable::kPending, "data") + " ORDER BY x, y, z, version;",
                         "reading the pending points");
  if (!st) return st.status();
  std::vector<PendingPoints> out;
  StoredChunk row;
  for (const sql::Row& r : st->rows()) {
    DF_RETURN_IF_ERROR(s.decode_chunk_row(r, ChunkTable::kPending, &row));
    out.push_back({row.info.key, row.info.version, std::move(row.chunk.points_for_write())});
  }
  DF_RETURN_IF_ERROR(st->status());
  return out;
}

Status ScanStore::for_each_chunk(const std::function<Status(const ChunkInfo&, PointArrays&)>& fn,
                                 const ChunkFilter& filter) {
  Impl& s = *impl_;
  std::string sql = select_chunks(ChunkTable::kChunks, "data");
  if (filter.bbox_m)
    sql += " WHERE max_x >= ? AND min_x <= ? AND max_y >= ? AND min_y <= ? AND max_z >= ? AND "
           "min_z <= ?";
  sql += " ORDER BY x, y, z;";
  auto st = s.db.prepare(sql, "reading chunks");
  if (!st) return st.status();
  if (filter.bbox_m) {
    for (int i = 0; i < 3; ++i) {
      st->bind(1 + 2 * i, static_cast<double>(filter.bbox_m->min()[i]));
      st->bind(2 + 2 * i, static_cast<double>(filter.bbox_m->max()[i]));
    }
  }
  StoredChunk chunk;
  for (const sql::Row& row : st->rows()) {
    Status decoded = s.decode_chunk_row(row, ChunkTable::kChunks, &chunk);
    if (!decoded) {
      if (!filter.on_damaged) return decoded;
      filter.on_damaged(decoded);
      continue;
    }
    DF_RETURN_IF_ERROR(fn(chunk.info, chunk.chunk.points_for_write()));
  }
  return st->status();
}

Result<std::vector<PoseRecord>> ScanStore::read_poses() {
  Impl& s = *impl_;
  ScopedRead snapshot(*this);  // the graph row the anchored poses are relative to, and the rows
  auto anchors = s.graph_anchors();
  if (!anchors) return anchors.status();
  return s.db.collect<PoseRecord>(
      std::string("SELECT ") + kPoseColumns + " FROM poses WHERE " + kCommittedFrames +
          " ORDER BY frame_id;",
      "reading poses", [&](const sql::Row& row) { return s.pose_of(row, **anchors); });
}

Result<std::vector<KeyframeInfo>> ScanStore::list_keyframes(
    const std::function<void(const Status&)>& on_damaged) {
  Impl& s = *impl_;
  ScopedRead snapshot(*this);
  auto anchors = s.graph_anchors();
  if (!anchors) return anchors.status();
  auto st = s.db.prepare(std::string("SELECT ") + kKeyframeColumns +
                             ", length(depth), COALESCE(length(color), 0) FROM keyframes WHERE " +
                             kCommittedFrames + " ORDER BY frame_id;",
                         "listing keyframes");
  if (!st) return st.status();
  std::vector<KeyframeInfo> out;
  for (const sql::Row& row : st->rows()) {
    Keyframe head;
    Status checked = s.keyframe_head_of(row, **anchors, &head);
    if (!checked) {
      if (!on_damaged) return checked;
      on_damaged(checked);
      continue;
    }
    KeyframeInfo k;
    k.frame_id = head.frame_id;
    k.utime = head.utime;
    k.width = head.intrinsics.width;
    k.height = head.intrinsics.height;
    k.T_world_cam = head.T_world_cam;
    k.depth_bytes = static_cast<size_t>(row.int64(KeyframeCol::kDepth));
    k.color_bytes = static_cast<size_t>(row.int64(KeyframeCol::kColor));
    out.push_back(std::move(k));
  }
  DF_RETURN_IF_ERROR(st->status());
  return out;
}

Result<Keyframe> ScanStore::read_keyframe(uint32_t frame_id) {
  Impl& s = *impl_;
  const std::string what = s.path + ": keyframe " + std::to_string(frame_id);
  ScopedRead snapshot(*this);
  auto anchors = s.graph_anchors();
  if (!anchors) return anchors.status();
  auto st = s.db.prepare(std::string("SELECT ") + kKeyframeColumns +
                             ", depth, color FROM keyframes WHERE frame_id = ?;",
                         "reading keyframe " + std::to_string(frame_id));
  if (!st) return st.status();
  st->bind(1, frame_id);
  auto found = st->step();
  if (!found) return found.status();
  if (!*found) return not_found(s.path + ": no keyframe " + std::to_string(frame_id));
  const sql::Row row = st->row();
  Keyframe k;
  DF_RETURN_IF_ERROR(s.keyframe_head_of(row, **anchors, &k));
  DF_RETURN_IF_ERROR(s.codec.decode_depth(row.blob(KeyframeCol::kDepth), row.blob_size(KeyframeCol::kDepth),
                                          what + " depth", &k.depth));
  if (k.depth.width != k.intrinsics.width || k.depth.height != k.intrinsics.height)
    return corrupt(what + ": depth is " + std::to_string(k.depth.width) + "x" +
                   std::to_string(k.depth.height) + ", intrinsics say " +
                   std::to_string(k.intrinsics.width) + "x" + std::to_string(k.intrinsics.height));
  if (!row.is_null(KeyframeCol::kColor)) {
    DF_RETURN_IF_ERROR(s.codec.decode_color(row.blob(KeyframeCol::kColor),
                                            row.blob_size(KeyframeCol::kColor), what + " colour", &k.color));
    if (k.color.width != k.depth.width || k.color.height != k.depth.height)
      return corrupt(what + ": colour and depth sizes differ");
  }
  return k;
}

Result<std::optional<CheckpointRecord>> ScanStore::last_checkpoint() {
  Impl& s = *impl_;
  auto st = s.db.prepare(std::string("SELECT ") + kCheckpointColumns +
                             " FROM checkpoints ORDER BY id DESC LIMIT 1;",
                         "reading the last checkpoint");
  if (!st) return st.status();
  auto found = st->step();
  if (!found) return found.status();
  if (!*found) return std::optional<CheckpointRecord>();
  auto rec = s.checkpoint_of(st->row());
  if (!rec) return rec.status();
  return std::optional<CheckpointRecord>(std::move(rec).value());
}

Result<std::vector<CheckpointRecord>> ScanStore::checkpoints() {
  Impl& s = *impl_;
  return s.db.collect<CheckpointRecord>(
      std::string("SELECT ") + kCheckpointColumns + " FROM checkpoints ORDER BY id;",
      "reading checkpoints", [&](const sql::Row& row) { return s.checkpoint_of(row); });
}

Result<StoreSummary> ScanStore::summary() {
  Impl& s = *impl_;
  ScopedRead snapshot(*this);
  DF_RETURN_IF_ERROR(snapshot.status());
  StoreSummary sum;
  sum.path = s.path;
  sum.schema_version = s.schema_version;
  auto meta = metadata();
  if (!meta) return meta.status();
  sum.metadata = *meta;
  auto config = config_toml();
  if (!config) return config.status();
  sum.has_config = config->has_value();
  auto st = s.db.prepare(
      "SELECT COUNT(*), COALESCE(SUM(point_count), 0), MIN(min_x), MIN(min_y), MIN(min_z), "
      "MAX(max_x), MAX(max_y), MAX(max_z), COALESCE(SUM(length(data)), 0) FROM chunks;",
      "summarising chunks");
  if (!st) return st.status();
  auto found = st->step();
  if (!found) return found.status();
  const sql::Row row = st->row();
  sum.chunk_count = static_cast<size_t>(row.int64(0));
  sum.point_count = static_cast<uint64_t>(row.int64(1));
  sum.extent_m.setEmpty();
  if (!row.is_null(2)) {
    sum.extent_m.min() = Eigen::Vector3f(row.real(2), row.real(3), row.real(4));
    sum.extent_m.max() = Eigen::Vector3f(row.real(5), row.real(6), row.real(7));
  }
  sum.chunk_bytes = static_cast<uint64_t>(row.int64(8));
  auto count = [&](const std::string& sql, const char* what, auto* out) -> Status {
    auto n = s.db.query_int(sql, what);
    if (!n) return n.status();
    *out = static_cast<std::remove_pointer_t<decltype(out)>>(*n);
    return Status::ok();
  };
  DF_RETURN_IF_ERROR(count("SELECT COUNT(*) FROM poses WHERE " + kCommittedFrames + ";",
                           "counting poses", &sum.pose_count));
  DF_RETURN_IF_ERROR(count("SELECT COUNT(*) FROM keyframes WHERE " + kCommittedFrames + ";",
                           "counting keyframes", &sum.keyframe_count));
  DF_RETURN_IF_ERROR(
      count("SELECT COALESCE(SUM(length(depth) + COALESCE(length(color), 0)), 0) FROM keyframes "
            "WHERE " + kCommittedFrames + ";",
            "measuring keyframes", &sum.keyframe_bytes));
  DF_RETURN_IF_ERROR(count("SELECT COUNT(*) FROM checkpoints;", "counting checkpoints",
                           &sum.checkpoint_count));
  DF_RETURN_IF_ERROR(count("SELECT COUNT(*) FROM chunk_staging;", "counting staged chunks",
                           &sum.staged_chunk_count));
  DF_RETURN_IF_ERROR(count("SELECT COUNT(*) FROM chunk_pending;", "counting pending points",
                           &sum.pending_rows));
  DF_RETURN_IF_ERROR(count("SELECT COALESCE(SUM(point_count), 0) FROM chunk_pending;",
                           "counting pending points", &sum.pending_points));
  auto last = last_checkpoint();
  if (!last) return last.status();
  sum.last_checkpoint = *last;
  // A damaged graph is the integrity check's to report in full; the summary says it is there.
  auto graph = graph_summary();
  if (graph) sum.graph = *graph;
  else sum.graph_problem = graph.status().message();
  sum.file_bytes = file_size(s.path);
  sum.wal_bytes = file_size(s.path + "-wal");
  return sum;
}

Status ScanStore::copy_to(const std::string& path) {
  Impl& s = *impl_;
  if (file_exists(path)) return invalid_argument(path + ": already exists");
  auto st = s.db.prepare("VACUUM INTO ?;", "copying to " + path);
  if (!st) return st.status();
  st->bind(1, path);
  Status done = st->run();
  if (!done) ::unlink(path.c_str());
  return done;
}

}  // namespace depthfuse::store
