// Checking a scan file: SQLite's own integrity check, the stored frame numbers against each other,
// then every chunk, keyframe and pose decoded and checksummed, and every chunk's row checked
// against its points. Rows written before their table had a checksum (poses before schema 3,
// keyframes and checkpoints before 4) are counted as unchecked; a later row without one is damage.
// Finds all problems rather than stopping at the first. Runs in the CLI (depthfuse inspect) and
// the tests, on a reader.
#include <cstdint>
#include <cstdlib>

#include "depthfuse/store/scan_recorder.hpp"
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

// Where the rows of `table` start to carry a checksum, by `key` (a frame id, a checkpoint id):
// what the migration that added the column recorded in meta `meta_key`; in a file from before it
// recorded that, the first row that has one. A row from there on without one was altered.
Result<int64_t> checksums_from(ScanStore::Impl& s, const std::string& table, const std::string& key,
                               const std::string& meta_key) {
  auto recorded = s.get_meta(meta_key);
  if (!recorded) return recorded.status();
  if (*recorded) {
    char* end = nullptr;
    const long long from = std::strtoll((*recorded)->c_str(), &end, 10);
    if (end == (*recorded)->c_str() || *end != '\0' || from < 1)
      return corrupt(s.path + ": meta " + meta_key + " '" + **recorded + "' is not a row id");
    return static_cast<int64_t>(from);
  }
  return s.db.query_int("SELECT COALESCE(MIN(" + key + "), " + std::to_string(INT64_MAX) +
                            ") FROM " + table + " WHERE checksum IS NOT NULL;",
                        "finding the first checksummed row of " + table);
}

// "<path>: pose of frame 7 has no checksum, though every pose from frame 1 on carries one ..."
std::string no_checksum(const std::string& path, const std::string& row, const std::string& rows,
                        int64_t from, int schema) {
  return path + ": " + row + " has no checksum, though every " + rows + " " +
         std::to_string(from) + " on carries one (schema " + std::to_string(schema) +
         "): the row was altered or damaged";
}

// Every chunk blob, resident and staged: decodes, checksums match, and its row's count and bounds
// agree.
void check_chunk_rows(ScanStore::Impl& s, IntegrityReport* rep) {
  auto chunks_from =
      checksums_from(s, "chunks", "checkpoint_id", "chunk_checksums_from_checkpoint");
  if (!chunks_from) rep->problems.push_back(chunks_from.status().message());
  for (const bool staged : {false, true}) {
    StoredChunk c;
    const ChunkTable table = staged ? ChunkTable::kStaging : ChunkTable::kChunks;
    check_rows(
        s.db, select_chunks(table, "data") + " ORDER BY x, y, z;",
        staged ? "reading chunk_staging" : "reading chunks",
        [&](const sql::Row& row) {
          ++rep->chunks_checked;
          DF_RETURN_IF_ERROR(s.decode_chunk_row(row, table, &c));
          if (!c.info.checksummed) {
            // Rows older than schema 6 have none; a staged one cannot be (a writer's open empties
            // the staging table after migrating).
            if (!chunks_from || staged || c.info.checkpoint_id >= *chunks_from)
              return corrupt(
                  no_checksum(s.path, (staged ? "staged chunk " : "chunk ") + to_string(c.info.key),
                              "chunk from checkpoint", chunks_from ? *chunks_from : 1, 6));
            ++rep->chunks_unchecked;
          }
          if (c.info.point_count == 0) return Status::ok();
          const Eigen::AlignedBox3f box = bounds_of(c.chunk.points());
          if (!box.min().isApprox(c.info.bounds_m.min(), 1e-5f) ||
              !box.max().isApprox(c.info.bounds_m.max(), 1e-5f))
            return corrupt(s.path + ": chunk " + to_string(c.info.key) +
                           ": stored bounds disagree with its points");
          return Status::ok();
        },
        rep);
  }
}

// Every keyframe row decoded, and the keyframe and checkpoint rows without a checksum.
void check_keyframe_rows(ScanStore& store, ScanStore::Impl& s, IntegrityReport* rep) {
  std::vector<uint32_t> keyframe_ids;
  check_rows(
      s.db, "SELECT frame_id FROM keyframes ORDER BY frame_id;", "listing keyframes",
      [&](const sql::Row& row) {
        keyframe_ids.push_back(static_cast<uint32_t>(row.int64(0)));
        return Status::ok();
      },
      rep);
  for (uint32_t id : keyframe_ids) {
    ++rep->keyframes_checked;
    auto k = store.read_keyframe(id);
    if (!k) rep->problems.push_back(k.status().message());
  }
  // Keyframe and checkpoint rows without a checksum (read above): written before schema 4, or
  // altered.
  struct Unchecked {
    const char* table;
    const char* key;
    const char* meta_key;
    const char* row;   // "keyframe" 12
    const char* rows;  // "keyframe from frame" 1
    size_t* count;
  };
  for (const Unchecked& u :
       {Unchecked{"keyframes", "frame_id", "keyframe_checksums_from_frame", "keyframe",
                  "keyframe from frame", &rep->keyframes_unchecked},
        Unchecked{"checkpoints", "id", "checkpoint_checksums_from_id", "checkpoint",
                  "checkpoint from id", &rep->checkpoints_unchecked}}) {
    auto from = checksums_from(s, u.table, u.key, u.meta_key);
    if (!from) {
      rep->problems.push_back(from.status().message());
      continue;
    }
    check_rows(
        s.db, std::string("SELECT ") + u.key + " FROM " + u.table + " WHERE checksum IS NULL;",
        std::string("listing unchecked ") + u.table,
        [&](const sql::Row& row) {
          if (row.int64(0) < *from) {
            ++*u.count;
            return Status::ok();
          }
          return corrupt(no_checksum(s.path, u.row + (" " + std::to_string(row.int64(0))),
                                     u.rows, *from, 4));
        },
        rep);
  }
}

void check_pose_rows(ScanStore::Impl& s, IntegrityReport* rep) {
  // Every pose row: its checksum (schema 3), then its pose. Rows written before have none.
  auto poses_from = checksums_from(s, "poses", "frame_id", "pose_checksums_from_frame");
  if (!poses_from) rep->problems.push_back(poses_from.status().message());
  // Anchored poses are checked against the graph row's keyframes (a damaged row is the graph's
  // own problem, reported there; then none is resolved).
  std::vector<Pose> anchors;
  if (auto a = s.graph_anchors()) anchors = **a;
  check_rows(
      s.db, std::string("SELECT ") + kPoseColumns + " FROM poses ORDER BY frame_id;", "reading poses",
      [&](const sql::Row& row) -> Status {
        ++rep->poses_checked;
        bool checked = false;
        auto p = s.pose_of(row, anchors, &checked);
        if (checked || !poses_from) return p.status();
        if (row.int64(0) < *poses_from) {
          ++rep->poses_unchecked;
          return p.status();
        }
        return corrupt(no_checksum(s.path, "pose of frame " + std::to_string(row.int64(0)),
                                   "pose from frame", *poses_from, 3));
      },
      rep);
}

void check_graph(ScanStore& store, ScanStore::Impl& s, IntegrityReport* rep) {
  // The pose graph: every keyframe row and the graph's row, checked and decoded as a resume reads
  // them; the points pending for chunks that had not followed a correction, every row checked; and
  // the graph, the deformation and the pending points as a resume restores them.
  auto graph = store.read_graph();
  if (!graph) {
    rep->problems.push_back(graph.status().message());
  } else if (*graph) {
    rep->graph_keyframes_checked = (*graph)->graph.keyframes.size();
    ScanGraph restored(LoopClosureConfig{});
    const Status g = restored.restore((*graph)->graph);
    if (!g) rep->problems.push_back(s.path + ": " + g.message());
  }
  auto pending = store.read_pending();
  if (!pending) rep->problems.push_back(pending.status().message());
  else rep->pending_rows_checked = pending->size();
  if (!graph || !pending) return;
  MapDeformation deformation;
  PointMap map(1.0);  // only its version is set
  const Status d = restore_deformation(*graph, std::move(*pending), s.path, &deformation, &map);
  if (!d) rep->problems.push_back(d.message());
}

void check_frame_log(ScanStore& store, IntegrityReport* rep) {
  // The frame redo log after the last checkpoint: every record checked, as a resume reads it.
  // A damaged record is named; the records before it are still replayed.
  auto log = store.frame_log_summary();
  if (log) rep->frame_log = *log;
  else rep->problems.push_back(log.status().message());
  const Status logged = store.for_each_logged_frame([&](LoggedFrame&) {
    ++rep->log_records_checked;
    return Status::ok();
  });
  if (!logged)
    rep->problems.push_back(logged.message() + " (a resume replays the " +
                           std::to_string(rep->log_records_checked) + " records before it)");
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
  check_chunk_rows(s, &rep);
  check_keyframe_rows(*this, s, &rep);
  check_pose_rows(s, &rep);
  check_graph(*this, s, &rep);
  check_frame_log(*this, &rep);
  auto meta = metadata();
  if (!meta) rep.problems.push_back(meta.status().message());
  return rep;
}

}  // namespace depthfuse::store
