// Checking a scan file: SQLite's own integrity check, the stored frame numbers against each other,
// then every chunk, keyframe and pose decoded and checksummed (poses written before schema 3 have
// no checksum: counted as unchecked), and every chunk's row checked against its points. Finds all problems
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

std::vector<std::string> ScanStore::frame_problems() {
  Impl& s = *impl_;
  std::vector<std::string> problems;
  ScopedRead snapshot(*this);
  auto cps = checkpoints();
  if (!cps) return {cps.status().message()};
  const CheckpointRecord* prev = nullptr;
  for (const CheckpointRecord& c : *cps) {
    const std::string what = s.path + ": checkpoint " + std::to_string(c.id);
    if (prev && c.last_frame_id < prev->last_frame_id)
      problems.push_back(what + " holds frames up to " + std::to_string(c.last_frame_id) +
                         ", fewer than checkpoint " + std::to_string(prev->id) + " before it (" +
                         std::to_string(prev->last_frame_id) + ")");
    if (prev && c.frames_fused < prev->frames_fused)
      problems.push_back(what + " counts " + std::to_string(c.frames_fused) +
                         " frames fused, fewer than checkpoint " + std::to_string(prev->id) +
                         " before it (" + std::to_string(prev->frames_fused) + ")");
    prev = &c;
  }
  const uint32_t last = prev ? prev->last_frame_id : 0;
  auto st = s.db.prepare("SELECT COUNT(*), COALESCE(MIN(frame_id), 0), COALESCE(MAX(frame_id), 0) "
                         "FROM poses WHERE " + kCommittedFrames + ";",
                         "counting poses");
  if (!st) return {st.status().message()};
  auto row = st->step();
  if (!row) return {row.status().message()};
  const int64_t count = st->row().int64(0), first = st->row().int64(1), newest = st->row().int64(2);
  const std::string where = s.path + ": the last checkpoint";
  if (count > 0 && first < 1)
    problems.push_back(s.path + ": a pose has frame id " + std::to_string(first) + " (ids start at 1)");
  // (A file may hold no poses at all: the store's own tests write chunks only.)
  if (count > 0 && newest != last)
    problems.push_back(where + " holds frames up to " + std::to_string(last) +
                       " but the newest pose is of frame " + std::to_string(newest));
  if (prev && static_cast<uint64_t>(count) > prev->frames_fused)
    problems.push_back(where + " counts " + std::to_string(prev->frames_fused) + " frames fused but the file holds " +
                       std::to_string(count) + " poses");
  return problems;
}

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
  // A file SQLite cannot even check has no rows worth reading.
  if (!checked) return rep;
  for (std::string& p : frame_problems()) rep.problems.push_back(std::move(p));
  if (!check_blobs) return rep;
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
  // Keyframe and checkpoint rows written before schema 4 have no checksum: read above, counted here.
  for (auto [table, n] : {std::pair{"keyframes", &rep.keyframes_unchecked},
                          std::pair{"checkpoints", &rep.checkpoints_unchecked}}) {
    auto unchecked = s.db.query_int(std::string("SELECT COUNT(*) FROM ") + table +
                                        " WHERE checksum IS NULL;",
                                    std::string("counting unchecked ") + table);
    if (unchecked) *n = static_cast<size_t>(*unchecked);
    else rep.problems.push_back(unchecked.status().message());
  }
  // Every pose row: its checksum (schema 3), then its pose. Rows written before have none.
  check_rows(
      s.db, std::string("SELECT ") + kPoseColumns + " FROM poses ORDER BY frame_id;", "reading poses",
      [&](const sql::Row& row) -> Status {
        ++rep.poses_checked;
        bool checked = false;
        auto p = s.pose_of(row, &checked);
        if (!checked) ++rep.poses_unchecked;
        return p.status();
      },
      &rep);
  // The frame redo log after the last checkpoint: every record checked, as a resume reads it.
  // A damaged record is named; the records before it are still replayed.
  auto log = frame_log_summary();
  if (log) rep.frame_log = *log;
  else rep.problems.push_back(log.status().message());
  const Status logged = for_each_logged_frame([&](LoggedFrame&) {
    ++rep.log_records_checked;
    return Status::ok();
  });
  if (!logged)
    rep.problems.push_back(logged.message() + " (a resume replays the " +
                           std::to_string(rep.log_records_checked) + " records before it)");
  auto meta = metadata();
  if (!meta) rep.problems.push_back(meta.status().message());
  return rep;
}

}  // namespace depthfuse::store
