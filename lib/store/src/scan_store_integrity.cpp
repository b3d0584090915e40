// Checking a scan file: SQLite's own integrity check, then every chunk, keyframe and pose blob
// decoded and checksummed, and every chunk's row checked against its points. Finds all problems
// rather than stopping at the first. Runs in the CLI (depthfuse inspect) and the tests, on a
// reader.
#include "scan_store_internal.hpp"

namespace depthfuse::store {

namespace {

// Runs `sql` and hands each row to `fn`, which returns a problem or ok; collects the problems,
// and an error that ends the query. False when the query could not even be prepared.
template <typename Fn>
bool check_rows(sql::Database& db, const std::string& sql, const std::string& context, Fn&& fn,
                IntegrityReport* rep) {
  auto st = db.prepare(sql, context);
  if (!st) {
    rep->problems.push_back(st.status().message());
    return false;
  }
  for (const sql::Row& row : st->rows()) {
    const Status problem = fn(row);
    if (!problem) rep->problems.push_back(problem.message());
  }
  if (!st->status()) rep->problems.push_back(st->status().message());
  return true;
}

}  // namespace

Result<IntegrityReport> ScanStore::integrity_check(bool check_blobs) {
  Impl& s = *impl_;
  IntegrityReport rep;
  ScopedRead snapshot(*this);
  if (!snapshot.status()) rep.problems.push_back(snapshot.status().message());
  const bool checked = check_rows(
      s.db, "PRAGMA integrity_check(50);", "PRAGMA integrity_check",
      [&](const sql::Row& row) {
        const std::string line = row.text(0);
        if (line == "ok") return Status::ok();
        return corrupt(s.path + ": sqlite integrity_check: " + line);
      },
      &rep);
  // A file SQLite cannot even check has no blobs worth decoding.
  if (!checked || !check_blobs) return rep;
  // Every chunk blob: decodes, checksums match, and its row's count and bounds agree.
  for (const bool staged : {false, true}) {
    StoredChunk c;
    check_rows(
        s.db, select_chunks(staged, "data") + " ORDER BY x, y, z;",
        staged ? "reading chunk_staging" : "reading chunks",
        [&](const sql::Row& row) {
          ++rep.chunks_checked;
          DF_RETURN_IF_ERROR(s.decode_chunk_row(row, staged, &c));
          if (c.info.point_count == 0) return Status::ok();
          const Eigen::AlignedBox3f box = bounds_of(c.chunk.points);
          if (!box.min().isApprox(c.info.bounds_m.min(), 1e-5f) ||
              !box.max().isApprox(c.info.bounds_m.max(), 1e-5f))
            return corrupt(s.path + ": chunk " + to_string(c.info.key) +
                           ": stored bounds disagree with its points");
          return Status::ok();
        },
        &rep);
  }
  std::vector<uint32_t> keyframe_ids;
  check_rows(
      s.db, "SELECT frame_id FROM keyframes ORDER BY frame_id;", "listing keyframes",
      [&](const sql::Row& row) {
        keyframe_ids.push_back(static_cast<uint32_t>(row.int64(0)));
        return Status::ok();
      },
      &rep);
  for (uint32_t id : keyframe_ids) {
    ++rep.keyframes_checked;
    auto k = read_keyframe(id);
    if (!k) rep.problems.push_back(k.status().message());
  }
  check_rows(
      s.db, "SELECT frame_id, T_world_cam FROM poses ORDER BY frame_id;", "reading poses",
      [&](const sql::Row& row) {
        ++rep.poses_checked;
        Pose T;
        return decode_pose(row.blob(1), row.blob_size(1),
                           s.path + ": pose of frame " + std::to_string(row.int64(0)), &T);
      },
      &rep);
  auto cps = checkpoints();
  if (!cps) rep.problems.push_back(cps.status().message());
  auto meta = metadata();
  if (!meta) rep.problems.push_back(meta.status().message());
  return rep;
}

}  // namespace depthfuse::store
