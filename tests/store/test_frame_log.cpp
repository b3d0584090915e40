// The frame redo log (docs/checkpoint-format.md): a recorder killed after log-only commits resumes
// to exactly the map, next frame id and pose it had; export of the killed file folds the logged
// frames in; frames after a correction wait for the checkpoint that takes it; a damaged record is
// named and the records before it still count; a schema-4 file opens (migrated); the fusion thread
// exports and checkpoints while the log's thread commits.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <filesystem>
#include <map>
#include <tuple>

#include "depthfuse/pipeline.hpp"
#include "depthfuse/store/export.hpp"
#include "depthfuse/store/frame_log_replay.hpp"
#include "depthfuse/store/scan_recorder.hpp"
#include "store_test_util.hpp"

using namespace depthfuse;
using namespace depthfuse::store;
using test::bit_equal;
using test::ChunkContents;
using test::expect_same_cloud;
using test::point_total;
using test::TempDir;

namespace {

ReconstructionConfig config() { return ReconstructionConfig{}.with_method(Method::kFull); }

RecorderConfig logging_config() {
  RecorderConfig rc;
  rc.bounded_memory = false;  // the whole map stays in memory: compared chunk by chunk
  rc.keyframe_every_n_frames = 5;
  rc.frame_log_interval_s = 0.05;
  return rc;
}

ChunkContents contents(const PointMap& map) {
  ChunkContents out;
  map.for_each_chunk([&](const ChunkKey& k, const Chunk& c) {
    if (!c.points().empty()) out[k] = c.points();
  });
  return out;
}

// A new scan file at `path` recording with logging_config().
Result<std::unique_ptr<ScanRecorder>> new_recorder(const std::string& path, const std::string& scan_id) {
  ScanMetadata meta;
  meta.scan_id = scan_id;
  meta.chunk_size_m = config().fusion.chunk_size_m;
  return ScanRecorder::create(path, meta, "", "", logging_config());
}

// What the live reconstructor had when its recorder was "killed".
struct Killed {
  ChunkContents cloud;
  uint32_t next_frame_id = 0;
  Pose last_pose = Pose::Identity();
  uint32_t checkpoint_frame = 0;   // the last full checkpoint's
  size_t logged = 0;               // frames after it
};

// Fuses `n` corridor frames into a new scan at `path` with a full checkpoint after frame
// `checkpoint_after`, then commits the log and destroys the recorder without finish() (a crash
// after the log's last commit).
Killed run_and_kill(const std::string& path, int n, int checkpoint_after) {
  Killed k;
  test::Corridor corridor;
  corridor.length_m = 8.0;
  IncrementalReconstructor live(config());
  auto rec = new_recorder(path, "log");
  EXPECT_TRUE(rec) << rec.status().to_string();
  if (!rec) return k;
  for (int i = 0; i < n; ++i) {
    const Frame f = corridor.render(corridor.pose(i, n), test::small_camera(), static_cast<uint32_t>(i));
    EXPECT_TRUE((*rec)->prepare_frame(f, live.initial_pose(f, std::nullopt), live));
    auto rep = live.process(f);
    EXPECT_TRUE(rep) << rep.status().to_string();
    if (!rep || !rep->fused()) continue;
    EXPECT_TRUE((*rec)->record_frame(f, *rep, &live.map()));
    if (i == checkpoint_after) {
      auto cp = (*rec)->checkpoint(&live.map(), "periodic");
      EXPECT_TRUE(cp) << cp.status().to_string();
      if (cp) k.checkpoint_frame = cp->last_frame_id;
    } else if (i > checkpoint_after) {
      ++k.logged;
    }
  }
  const Status flushed = (*rec)->flush_frame_log();
  EXPECT_TRUE(flushed) << flushed.to_string();
  // Those before the checkpoint may have been dropped unwritten once it committed.
  EXPECT_GE((*rec)->status().frame_log.frames_logged, static_cast<uint64_t>(k.logged));
  k.cloud = contents(live.map());
  k.next_frame_id = live.next_frame_id();
  k.last_pose = *live.last_pose();
  rec->reset();  // killed: no finish(), no checkpoint
  return k;
}

// The CLI's exit code; its output in *out.
int run_cli(const std::string& args, std::string* out) {
  const test::Proc r = test::run(std::string(DEPTHFUSE_CLI) + " " + args);
  *out = r.output;
  return r.code;
}

using test::exec_sql;

TEST(FrameLog, KilledAfterLogOnlyCommitsResumesToTheSameMapAndFrameId) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  const Killed k = run_and_kill(path, 40, 9);
  ASSERT_GT(k.logged, 20u);
  ASSERT_EQ(k.checkpoint_frame, 10u);

  {
    // Killed and not resumed: the file says what its log holds, and every record checks.
    auto ro = ScanStore::open(path, OpenMode::kReadOnly);
    ASSERT_TRUE(ro) << ro.status().to_string();
    auto log = (*ro)->frame_log_summary();
    ASSERT_TRUE(log) << log.status().to_string();
    EXPECT_EQ(log->count, k.logged);
    EXPECT_EQ(log->first_frame_id, k.checkpoint_frame + 1);
    EXPECT_EQ(log->last_frame_id, k.next_frame_id - 1);
    // (Records of the checkpoint's frames committed after it, log->stale, are left to the next
    // writer: the two threads race.)
    auto integrity = (*ro)->integrity_check();
    ASSERT_TRUE(integrity) << integrity.status().to_string();
    EXPECT_TRUE(integrity->ok()) << integrity->problems.front();
    EXPECT_EQ(integrity->log_records_checked, k.logged);
  }

  ResumePoint at;
  RecorderConfig rc = logging_config();
  auto rec = ScanRecorder::resume(path, rc, &at);
  ASSERT_TRUE(rec) << rec.status().to_string();
  EXPECT_EQ(at.next_frame_id, k.checkpoint_frame + 1);
  EXPECT_EQ(at.frame_log.count, k.logged);
  IncrementalReconstructor resumed(config());
  resumed.reset(std::move(at.map), at.next_frame_id, at.last_T_world_cam);
  // Until the log is replayed, recording would give new frames the logged frames' ids.
  FrameReport early;
  early.frame_id = at.next_frame_id;
  EXPECT_FALSE((*rec)->record_frame(Frame{}, early, &resumed.map()));
  auto replayed = (*rec)->replay_log(resumed);
  ASSERT_TRUE(replayed) << replayed.status().to_string();
  EXPECT_EQ(*replayed, k.logged);
  EXPECT_EQ(resumed.next_frame_id(), k.next_frame_id);
  ASSERT_TRUE(resumed.last_pose());
  EXPECT_TRUE(resumed.last_pose()->matrix() == k.last_pose.matrix());
  expect_same_cloud(contents(resumed.map()), k.cloud);
  // The replayed frames' poses are recorded again, for the next checkpoint.
  EXPECT_EQ((*rec)->pending_poses().size(), k.logged);
  EXPECT_EQ((*rec)->last_frame_id(), k.next_frame_id - 1);
  // A checkpoint now holds them, and drops their records.
  auto cp = (*rec)->checkpoint(&resumed.map(), "periodic");
  ASSERT_TRUE(cp) << cp.status().to_string();
  EXPECT_EQ(cp->last_frame_id, k.next_frame_id - 1);
  auto log = (*rec)->store().frame_log_summary();
  ASSERT_TRUE(log);
  EXPECT_EQ(log->count + log->stale, 0u);
  EXPECT_TRUE((*rec)->store().frame_problems().empty());
}

TEST(FrameLog, ExportOfAKilledUnresumedFileFoldsTheLoggedFramesIn) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  const Killed k = run_and_kill(path, 40, 9);
  ASSERT_GT(k.logged, 20u);
  auto ro = ScanStore::open(path, OpenMode::kReadOnly);
  ASSERT_TRUE(ro) << ro.status().to_string();
  auto replay = replay_frame_log(**ro, config());
  ASSERT_TRUE(replay) << replay.status().to_string();
  EXPECT_TRUE(replay->damaged) << replay->damaged.to_string();
  EXPECT_EQ(replay->poses.size(), k.logged);
  // The folded chunks with the file's others are the live map.
  ChunkContents got;
  ASSERT_TRUE((*ro)->for_each_chunk([&](const ChunkInfo& info, PointArrays& a) {
    got[info.key] = std::move(a);
    return Status::ok();
  }));
  const size_t checkpoint_points = point_total(got);
  for (auto& [key, c] : contents(*replay->map)) got[key] = c;
  expect_same_cloud(got, k.cloud);
  ExportOptions options;
  options.replacing = replay->map.get();
  auto exported = export_cloud(**ro, dir.file("cloud.ply"), options);
  ASSERT_TRUE(exported) << exported.status().to_string();
  EXPECT_EQ(exported->points_written, point_total(k.cloud));
  EXPECT_GT(exported->points_written, checkpoint_points) << "the logged frames added points";
  auto plain = export_cloud(**ro, dir.file("checkpoint.ply"));
  ASSERT_TRUE(plain);
  EXPECT_EQ(plain->points_written, checkpoint_points);

  // The CLI does the same, and says so.
  std::string out;
  EXPECT_EQ(run_cli("export " + path + " -o " + dir.file("cli.ply"), &out), 0) << out;
  EXPECT_NE(out.find("wrote " + std::to_string(point_total(k.cloud)) + " points"), std::string::npos) << out;
  EXPECT_NE(out.find(std::to_string(k.logged) + " logged frames folded in"), std::string::npos) << out;
  EXPECT_NE(run_cli("export " + path + " --mesh -o " + dir.file("mesh.ply"), &out), 0);
  EXPECT_NE(out.find("depthfuse inspect --fold-log"), std::string::npos) << out;
  EXPECT_EQ(run_cli("inspect " + path, &out), 0) << out;
  EXPECT_NE(out.find("frame log      " + std::to_string(k.logged) + " frames (" +
                     std::to_string(k.checkpoint_frame + 1) + "-" + std::to_string(k.next_frame_id - 1) + ")"),
            std::string::npos) << out;
  EXPECT_NE(out.find(std::to_string(k.logged) + " frame log records decoded and checksummed"),
            std::string::npos) << out;
}

// A checkpoint drops the log records of its frames, 30 s of frames by default. Freeing those
// pages must not write them again (SQLite's secure delete, on in Debian's build, zeroes each freed
// page through the WAL): that held the store, and the fusion thread behind it.
TEST(FrameLog, ACheckpointDropsItsRecordsWithoutWritingThemAgain) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  constexpr int kRecords = 40;
  constexpr size_t kBlobBytes = 256 * 1024;
  uint64_t logged_bytes = 0;
  {
    ScanMetadata meta;
    meta.scan_id = "drop";
    auto store = ScanStore::open(path, OpenMode::kCreate);
    ASSERT_TRUE(store) << store.status().to_string();
    ASSERT_TRUE((*store)->set_metadata(meta));
    std::vector<FrameLogRecord> batch(1);
    uint32_t bits = 12345;
    for (int i = 0; i < kRecords; ++i) {
      FrameLogRecord& r = batch[0];
      r.pose.frame_id = static_cast<uint32_t>(i + 1);
      r.intrinsics = test::small_camera();
      r.depth.resize(kBlobBytes);
      for (uint8_t& b : r.depth) b = static_cast<uint8_t>((bits = bits * 1664525u + 1013904223u) >> 24);
      ASSERT_TRUE((*store)->append_frame_log(batch));
      logged_bytes += kBlobBytes;
    }
  }  // closing merges the WAL into the file and removes it
  auto store = ScanStore::open(path, OpenMode::kReadWrite);
  ASSERT_TRUE(store) << store.status().to_string();
  ASSERT_TRUE((*store)->begin_checkpoint(kRecords));
  CheckpointInfo info;
  info.reason = "periodic";
  info.last_frame_id = kRecords;
  info.frames_fused = kRecords;
  auto cp = (*store)->commit_checkpoint(info);
  ASSERT_TRUE(cp) << cp.status().to_string();
  auto log = (*store)->frame_log_summary();
  ASSERT_TRUE(log);
  EXPECT_EQ(log->count + log->stale, 0u);
  // The WAL holds what the checkpoint wrote: its rows and the free-list and pointer-map pages,
  // not the 10 MB it dropped.
  const auto wal_bytes = std::filesystem::file_size(path + "-wal");
  EXPECT_LT(wal_bytes, logged_bytes / 20) << "the checkpoint wrote " << wal_bytes
                                           << " bytes to drop " << logged_bytes;
}

// The log holds poses, not corrections: a frame fused after a correction and replayed over the
// map of before it would land where that map was. Such frames are left out until a checkpoint
// takes the correction; the frames after that checkpoint are logged again.
TEST(FrameLog, FramesAfterACorrectionAreLoggedOnlyOnceACheckpointTookIt) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  test::Corridor corridor;
  IncrementalReconstructor live(config());
  auto rec = new_recorder(path, "corrected");
  ASSERT_TRUE(rec) << rec.status().to_string();
  constexpr int n = 15, corrected_after = 4, checkpoint_after = 9;
  AppliedCorrection correction;
  correction.version = 1;
  correction.first_frame_id = {1};
  correction.motion = {Pose::Identity()};
  for (int i = 0; i < n; ++i) {
    const Frame f = corridor.render(corridor.pose(i, n), test::small_camera(), static_cast<uint32_t>(i));
    ASSERT_TRUE((*rec)->prepare_frame(f, live.initial_pose(f, std::nullopt), live));
    auto rep = live.process(f);
    ASSERT_TRUE(rep && rep->fused());
    ASSERT_TRUE((*rec)->record_frame(f, *rep, &live.map()));
    if (i == corrected_after) (*rec)->poses_corrected(correction, rep->frame_id + 1);
    if (i == checkpoint_after) {
      ASSERT_TRUE((*rec)->checkpoint(&live.map(), "periodic"));
    }
  }
  ASSERT_TRUE((*rec)->flush_frame_log());
  EXPECT_EQ((*rec)->status().frames_not_logged_after_correction,
            static_cast<uint64_t>(checkpoint_after - corrected_after));
  auto store = ScanStore::open(path, OpenMode::kReadOnly);
  ASSERT_TRUE(store) << store.status().to_string();
  auto log = (*store)->frame_log_summary();
  ASSERT_TRUE(log);
  EXPECT_EQ(log->count, static_cast<size_t>(n - 1 - checkpoint_after));
  EXPECT_EQ(log->first_frame_id, static_cast<uint32_t>(checkpoint_after + 2));
}

TEST(FrameLog, DamagedRecordIsNamedAndTheRecordsBeforeItAreReplayed) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  const Killed k = run_and_kill(path, 40, 9);
  ASSERT_GT(k.logged, 20u);
  const uint32_t bad = k.checkpoint_frame + 15;
  exec_sql(path, "UPDATE frame_log SET checksum = checksum + 1 WHERE frame_id = " + std::to_string(bad) + ";");
  {
    auto ro = ScanStore::open(path, OpenMode::kReadOnly);
    ASSERT_TRUE(ro);
    auto integrity = (*ro)->integrity_check();
    ASSERT_TRUE(integrity);
    ASSERT_FALSE(integrity->ok());
    bool named = false;
    for (const std::string& p : integrity->problems)
      named |= p.find("frame log record of frame " + std::to_string(bad) + ": checksum mismatch") !=
               std::string::npos;
    EXPECT_TRUE(named) << integrity->problems.front();
    EXPECT_EQ(integrity->log_records_checked, 14u);
    auto replay = replay_frame_log(**ro, config());
    ASSERT_TRUE(replay) << replay.status().to_string();
    EXPECT_EQ(replay->damaged.code(), StatusCode::kCorrupt);
    EXPECT_EQ(replay->poses.size(), 14u);
  }
  ResumePoint at;
  auto rec = ScanRecorder::resume(path, logging_config(), &at);
  ASSERT_TRUE(rec) << rec.status().to_string();
  IncrementalReconstructor resumed(config());
  resumed.reset(std::move(at.map), at.next_frame_id, at.last_T_world_cam);
  auto replayed = (*rec)->replay_log(resumed);
  ASSERT_TRUE(replayed) << replayed.status().to_string();
  EXPECT_EQ(*replayed, 14u);
  EXPECT_EQ(resumed.next_frame_id(), bad);
  // The damaged record and those after it are gone: the next frames take their ids.
  auto log = (*rec)->store().frame_log_summary();
  ASSERT_TRUE(log);
  EXPECT_EQ(log->last_frame_id, bad - 1);
}

TEST(FrameLog, SchemaFourFileOpensMigrated) {
  TempDir dir;
  const std::string path = dir.file("v4.db");
  {
    auto s = ScanStore::open(path, OpenMode::kCreate);
    ASSERT_TRUE(s) << s.status().to_string();
    ASSERT_TRUE((*s)->begin_checkpoint());
    PoseRecord p;
    p.frame_id = 1;
    p.utime = 7;
    ASSERT_TRUE((*s)->write_pose(p));
    CheckpointInfo info;
    info.last_frame_id = 1;
    info.frames_fused = 1;
    ASSERT_TRUE((*s)->commit_checkpoint(info));
  }
  // Schema 5 is schema 4 and the frame_log table: without it, the file is what schema 4 wrote.
  exec_sql(path, test::as_schema_5_sql() + "DROP TABLE frame_log; PRAGMA user_version = 4;");
  auto ro = ScanStore::open(path, OpenMode::kReadOnly);
  ASSERT_FALSE(ro);
  EXPECT_NE(ro.status().message().find("depthfuse inspect --upgrade"), std::string::npos)
      << ro.status().to_string();
  {
    auto rw = ScanStore::open(path, OpenMode::kReadWrite);
    ASSERT_TRUE(rw) << rw.status().to_string();
    EXPECT_TRUE((*rw)->open_report().migrated);
    EXPECT_EQ((*rw)->open_report().found_schema_version, 4);
    EXPECT_EQ((*rw)->schema_version(), kSchemaVersion);
  }
  auto after = ScanStore::open(path, OpenMode::kReadOnly);
  ASSERT_TRUE(after) << after.status().to_string();
  auto log = (*after)->frame_log_summary();
  ASSERT_TRUE(log) << log.status().to_string();
  EXPECT_EQ(log->count, 0u);
  auto poses = (*after)->read_poses();
  ASSERT_TRUE(poses);
  ASSERT_EQ(poses->size(), 1u);
  EXPECT_EQ((*poses)[0].utime, 7);
  auto integrity = (*after)->integrity_check();
  ASSERT_TRUE(integrity);
  EXPECT_TRUE(integrity->ok());
}

}  // namespace

// The fusion thread reads and writes the file (an export, as at a scan's stop; checkpoints on
// command; keyframes) while the log's thread commits every few milliseconds: each thread on its own
// connection, nothing fails. With one connection shared under the recorder's mutex, which the
// export did not take, an export's read and a log commit met on it: "cannot start a transaction
// within a transaction" (issue 36).
TEST(FrameLog, TheFusionThreadExportsAndCheckpointsWhileTheLogCommits) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  test::Corridor corridor;
  corridor.length_m = 8.0;
  IncrementalReconstructor live(config());
  ScanMetadata meta;
  meta.chunk_size_m = config().fusion.chunk_size_m;
  RecorderConfig rc = logging_config();
  rc.frame_log_interval_s = 0.004;  // commits due every 2 ms
  rc.keyframe_every_n_frames = 2;
  auto rec = ScanRecorder::create(path, meta, "", "", rc);
  ASSERT_TRUE(rec) << rec.status().to_string();
  constexpr int kFrames = 20;
  for (int i = 0; i < kFrames; ++i) {
    const Frame f = corridor.render(corridor.pose(i, kFrames), test::small_camera(), static_cast<uint32_t>(i));
    ASSERT_TRUE((*rec)->prepare_frame(f, live.initial_pose(f, std::nullopt), live));
    auto rep = live.process(f);
    ASSERT_TRUE(rep) << rep.status().to_string();
    ASSERT_TRUE((*rec)->record_frame(f, *rep, &live.map()));
    for (int k = 0; k < 2; ++k) {
      auto exported = export_cloud((*rec)->store(), dir.file("cloud.ply"));
      ASSERT_TRUE(exported) << "frame " << i << ": " << exported.status().to_string();
    }
    if (i % 4 == 3) {
      auto cp = (*rec)->checkpoint(&live.map(), "command");
      ASSERT_TRUE(cp) << "frame " << i << ": " << cp.status().to_string();
    }
  }
  const Status flushed = (*rec)->flush_frame_log();
  EXPECT_TRUE(flushed) << flushed.to_string();
  const FrameLogStats& log = (*rec)->status().frame_log;
  EXPECT_EQ(log.failures, 0u) << log.last_error.to_string();
  EXPECT_GT(log.commits, 5u);
  auto done = (*rec)->finish(&live.map());
  ASSERT_TRUE(done) << done.status().to_string();
  auto exported = export_cloud((*rec)->store(), dir.file("final.ply"));
  ASSERT_TRUE(exported) << exported.status().to_string();
  EXPECT_EQ(exported->points_written, live.map().point_count());
}

// A schema-5 file (chunks without versions or checksums, no pose graph) migrates when a writer
// opens it and resumes: its chunks come back at version 0, counted as unchecked, and a checkpoint
// after the migration writes checksummed chunks and a graph.
TEST(SchemaSix, ASchemaFiveFileMigratesAndResumes) {
  TempDir dir;
  const std::string path = dir.file("v5.db");
  const ChunkKey key{1, 0, 0};
  {
    auto s = ScanStore::open(path, OpenMode::kCreate);
    ASSERT_TRUE(s) << s.status().to_string();
    ASSERT_TRUE((*s)->begin_checkpoint());
    Chunk c;
    c.points_for_write() = test::make_points(key, 1, 50);
    ASSERT_TRUE((*s)->write_chunk(key, c));
    PoseRecord p;
    p.frame_id = 1;
    ASSERT_TRUE((*s)->write_pose(p));
    CheckpointInfo info;
    info.last_frame_id = 1;
    info.frames_fused = 1;
    ASSERT_TRUE((*s)->commit_checkpoint(info));
  }
  exec_sql(path, test::as_schema_5_sql());
  RecorderConfig rc;
  rc.bounded_memory = false;
  ResumePoint at;
  auto rec = ScanRecorder::resume(path, rc, &at);
  ASSERT_TRUE(rec) << rec.status().to_string();
  EXPECT_EQ((*rec)->store().open_report().found_schema_version, 5);
  EXPECT_FALSE(at.graph);
  ASSERT_TRUE(at.map->find(key));
  EXPECT_EQ(at.map->find(key)->version, 0u);
  EXPECT_EQ(at.map->find(key)->points().size(), 50u);
  auto integrity = (*rec)->store().integrity_check();
  ASSERT_TRUE(integrity);
  EXPECT_TRUE(integrity->ok()) << integrity->problems.front();
  EXPECT_EQ(integrity->chunks_unchecked, 1u);
  // The next checkpoint rewrites the chunk with its version and checksum, and writes the graph.
  at.map->find(key)->dirty = true;
  at.map->find(key)->version = 2;
  GraphCheckpoint g;
  g.graph.version = 2;
  g.deformation.oldest_version = 2;
  g.deformation.T_world_kf.emplace_back();
  g.deformation.max_motion_m.push_back(0);
  (*rec)->set_graph(g);
  ASSERT_TRUE((*rec)->checkpoint(at.map.get(), "command"));
  auto stored = (*rec)->store().read_chunk(key);
  ASSERT_TRUE(stored);
  EXPECT_EQ(stored->info.version, 2u);
  EXPECT_TRUE(stored->info.checksummed);
  auto graph = (*rec)->store().read_graph();
  ASSERT_TRUE(graph) << graph.status().to_string();
  EXPECT_TRUE(*graph);
  integrity = (*rec)->store().integrity_check();
  ASSERT_TRUE(integrity);
  EXPECT_TRUE(integrity->ok()) << integrity->problems.front();
  EXPECT_EQ(integrity->chunks_unchecked, 0u);
}

// A chunk row's version is covered by its checksum (a changed version would move or freeze the
// chunk's points on a resume), and a NULL checksum in a row written since schema 6 is damage.
TEST(SchemaSix, AChunkRowsVersionIsChecked) {
  TempDir dir;
  const std::string path = dir.file("v6.db");
  const ChunkKey key{1, 0, 0};
  {
    auto s = ScanStore::open(path, OpenMode::kCreate);
    ASSERT_TRUE(s) << s.status().to_string();
    ASSERT_TRUE((*s)->begin_checkpoint());
    Chunk c;
    c.points_for_write() = test::make_points(key, 1, 50);
    c.version = 3;
    ASSERT_TRUE((*s)->write_chunk(key, c));
    CheckpointInfo info;
    ASSERT_TRUE((*s)->commit_checkpoint(info));
  }
  auto integrity_problems = [&] {
    auto s = ScanStore::open(path, OpenMode::kReadOnly);
    EXPECT_TRUE(s) << s.status().to_string();
    auto r = (*s)->integrity_check();
    EXPECT_TRUE(r);
    return r->problems;
  };
  EXPECT_TRUE(integrity_problems().empty());
  exec_sql(path, "UPDATE chunks SET version = 4;");
  auto problems = integrity_problems();
  ASSERT_EQ(problems.size(), 1u);
  EXPECT_NE(problems[0].find("chunk (1,0,0): checksum mismatch"), std::string::npos) << problems[0];
  exec_sql(path, "UPDATE chunks SET version = 3, checksum = NULL;");
  problems = integrity_problems();
  ASSERT_EQ(problems.size(), 1u);
  EXPECT_NE(
      problems[0].find("chunk (1,0,0) has no checksum, though every chunk from checkpoint 1 on"),
      std::string::npos)
      << problems[0];
}
