// ScanStore on real SQLite files: bit-exact round trips, checkpoint atomicity and isolation,
// staging and crash recovery, the writer lock, schema migration, and damaged files.
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <sys/stat.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <random>

#include "depthfuse/store/blob_codec.hpp"
#include "depthfuse/store/scan_recorder.hpp"
#include "depthfuse/store/scan_store.hpp"
#include "store_test_util.hpp"

using namespace depthfuse;
using namespace depthfuse::store;
using test::bit_equal;
using test::make_points;
using test::TempDir;

namespace {

std::unique_ptr<ScanStore> open_or_die(const std::string& path, OpenMode mode) {
  auto s = ScanStore::open(path, mode);
  EXPECT_TRUE(s) << s.status().to_string();
  return s ? std::move(s).value() : nullptr;
}

Chunk chunk_of(const PointArrays& a, uint32_t touched = 7) {
  Chunk c;
  c.points_for_write() = a;
  c.last_touched_frame = touched;
  return c;
}

Pose some_pose(double t) {
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisd(t, Eigen::Vector3d(0.2, 1, 0.3).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(t, -t / 3.0, 1.0 + t * t);
  return T;
}

Keyframe some_keyframe(uint32_t id) {
  Keyframe k;
  k.frame_id = id;
  k.utime = 1000 + id;
  k.sensor_serial = "014845";
  k.intrinsics = test::small_camera();
  k.T_world_cam = some_pose(id * 0.1);
  k.depth = DepthImage(k.intrinsics.width, k.intrinsics.height);
  k.color.width = k.intrinsics.width;
  k.color.height = k.intrinsics.height;
  for (int i = 0; i < k.intrinsics.width * k.intrinsics.height; ++i) {
    k.depth.depth_m[i] = i % 5 ? 0.5f + 0.0001f * static_cast<float>((i * 7919) % 30000) : 0.0f;
    for (int c = 0; c < 3; ++c) k.color.rgb.push_back(static_cast<uint8_t>(i * (c + 3)));
  }
  return k;
}

void expect_same_pose(const Pose& a, const Pose& b) {
  EXPECT_EQ(std::memcmp(a.matrix().data(), b.matrix().data(), sizeof(double) * 16), 0);
}

// Runs one checkpoint writing the given chunks.
CheckpointRecord checkpoint(ScanStore& s, const std::vector<std::pair<ChunkKey, PointArrays>>& chunks,
                            uint32_t last_frame) {
  EXPECT_TRUE(s.begin_checkpoint());
  for (const auto& [k, a] : chunks) EXPECT_TRUE(s.write_chunk(k, chunk_of(a)));
  CheckpointInfo info;
  info.last_frame_id = last_frame;
  info.T_world_cam = some_pose(last_frame);
  auto rec = s.commit_checkpoint(info);
  EXPECT_TRUE(rec) << rec.status().to_string();
  return rec ? *rec : CheckpointRecord{};
}

}  // namespace

TEST(ScanStore, RoundTripIsBitExact) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  std::vector<std::pair<ChunkKey, PointArrays>> chunks;
  for (int i = 0; i < 20; ++i) {
    const ChunkKey k{i - 10, i % 3 - 1, -i};
    chunks.emplace_back(k, make_points(k, 1, 50 + 37 * i));
  }
  chunks[3].second.position_m[0].x() = -0.0f;
  chunks[4].second.state[1].nz = std::numeric_limits<float>::quiet_NaN();
  ScanMetadata meta;
  meta.scan_id = "room-17";
  meta.created_utime = 1700000000123456;
  meta.sensor_serial = "014845";
  meta.method = "full";
  meta.chunk_size_m = 0.5;
  meta.software_version = "0.1.0";
  const std::string toml = "[fusion]\nchunk_size_m = 0.5\n# ünïcødé\n";
  std::vector<PoseRecord> poses;
  {
    auto s = open_or_die(path, OpenMode::kCreate);
    ASSERT_TRUE(s);
    ASSERT_TRUE(s->set_metadata(meta));
    ASSERT_TRUE(s->set_config(toml, "/etc/depthfuse.toml"));
    ASSERT_TRUE(s->write_keyframe(some_keyframe(10)));
    ASSERT_TRUE(s->begin_checkpoint());
    for (const auto& [k, a] : chunks) ASSERT_TRUE(s->write_chunk(k, chunk_of(a, 40 + k.x)));
    for (uint32_t f = 1; f <= 12; ++f) {
      PoseRecord p;
      p.frame_id = f;
      p.utime = 1000 + f;
      p.T_world_cam = some_pose(f * 0.1);
      p.registered = f % 2;
      p.fitness = 0.9 + f * 1e-3;
      p.rmse_m = 1.0 / (f + 3);
      p.correspondences = 1000 + f;
      poses.push_back(p);
      ASSERT_TRUE(s->write_pose(p));
    }
    CheckpointInfo info;
    info.reason = "command";
    info.last_frame_id = 12;
    info.T_world_cam = some_pose(1.2);
    info.frames_received = 21;
    info.frames_fused = 12;
    info.frames_tracked_only = 4;
    info.frames_lost = 2;
    info.frames_dropped = 3;
    auto rec = s->commit_checkpoint(info);
    ASSERT_TRUE(rec) << rec.status().to_string();
    EXPECT_EQ(rec->id, 1);
    EXPECT_EQ(rec->chunk_count, chunks.size());
  }
  auto s = open_or_die(path, OpenMode::kReadOnly);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->schema_version(), kSchemaVersion);
  size_t total = 0;
  for (const auto& [k, a] : chunks) {
    auto c = s->read_chunk(k);
    ASSERT_TRUE(c) << c.status().to_string();
    EXPECT_TRUE(bit_equal(c->chunk.points(), a)) << to_string(k);
    EXPECT_EQ(c->chunk.last_touched_frame, static_cast<uint32_t>(40 + k.x));
    EXPECT_FALSE(c->chunk.dirty);
    total += a.size();
  }
  // Streaming iteration visits every chunk once, in key order.
  size_t visited = 0, streamed = 0;
  ChunkKey prev{INT32_MIN, 0, 0};
  ASSERT_TRUE(s->for_each_chunk([&](const ChunkInfo& info, PointArrays& a) {
    EXPECT_TRUE(std::tie(prev.x, prev.y, prev.z) < std::tie(info.key.x, info.key.y, info.key.z));
    prev = info.key;
    ++visited;
    streamed += a.size();
    return Status::ok();
  }));
  EXPECT_EQ(visited, chunks.size());
  EXPECT_EQ(streamed, total);
  auto read_poses = s->read_poses();
  ASSERT_TRUE(read_poses);
  ASSERT_EQ(read_poses->size(), poses.size());
  for (size_t i = 0; i < poses.size(); ++i) {
    const PoseRecord& a = poses[i];
    const PoseRecord& b = (*read_poses)[i];
    EXPECT_EQ(a.frame_id, b.frame_id);
    EXPECT_EQ(a.utime, b.utime);
    expect_same_pose(a.T_world_cam, b.T_world_cam);
    EXPECT_EQ(a.registered, b.registered);
    EXPECT_EQ(a.fitness, b.fitness);
    EXPECT_EQ(a.rmse_m, b.rmse_m);
    EXPECT_EQ(a.correspondences, b.correspondences);
  }
  auto kf = s->read_keyframe(10);
  ASSERT_TRUE(kf) << kf.status().to_string();
  const Keyframe ref = some_keyframe(10);
  EXPECT_TRUE(test::same_bits(kf->depth.depth_m, ref.depth.depth_m));
  EXPECT_EQ(kf->color.rgb, ref.color.rgb);
  EXPECT_EQ(kf->sensor_serial, ref.sensor_serial);
  EXPECT_EQ(kf->intrinsics.fx, ref.intrinsics.fx);
  expect_same_pose(kf->T_world_cam, ref.T_world_cam);
  const Frame f = kf->to_frame();
  ASSERT_TRUE(f.T_world_cam_hint.has_value());
  expect_same_pose(*f.T_world_cam_hint, ref.T_world_cam);
  auto m = s->metadata();
  ASSERT_TRUE(m);
  EXPECT_EQ(m->scan_id, meta.scan_id);
  EXPECT_EQ(m->created_utime, meta.created_utime);
  EXPECT_EQ(m->sensor_serial, meta.sensor_serial);
  EXPECT_EQ(m->frames_received, 21u);
  EXPECT_EQ(m->frames_fused, 12u);
  EXPECT_EQ(m->frames_tracked_only, 4u);
  EXPECT_EQ(m->frames_lost, 2u);
  EXPECT_EQ(m->frames_dropped, 3u);
  auto config = s->config_toml();
  ASSERT_TRUE(config && config->has_value());
  EXPECT_EQ(**config, toml);
  auto sum = s->summary();
  ASSERT_TRUE(sum) << sum.status().to_string();
  EXPECT_EQ(sum->point_count, total);
  EXPECT_EQ(sum->chunk_count, chunks.size());
  EXPECT_EQ(sum->pose_count, 12u);
  EXPECT_EQ(sum->keyframe_count, 1u);
  EXPECT_EQ(sum->checkpoint_count, 1u);
  ASSERT_TRUE(sum->last_checkpoint);
  EXPECT_EQ(sum->last_checkpoint->reason, "command");
  expect_same_pose(*sum->last_checkpoint->T_world_cam, some_pose(1.2));
  auto integrity = s->integrity_check();
  ASSERT_TRUE(integrity);
  EXPECT_TRUE(integrity->ok()) << integrity->problems.front();
  EXPECT_EQ(integrity->chunks_checked, chunks.size());
}

TEST(ScanStore, RolledBackCheckpointLeavesThePreviousOne) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  const ChunkKey a{0, 0, 0}, b{1, 0, 0}, c{2, 0, 0};
  auto s = open_or_die(path, OpenMode::kCreate);
  ASSERT_TRUE(s);
  checkpoint(*s, {{a, make_points(a, 1, 100)}, {b, make_points(b, 1, 100)}}, 10);

  ASSERT_TRUE(s->begin_checkpoint());
  ASSERT_TRUE(s->write_chunk(a, chunk_of(make_points(a, 2, 120))));
  ASSERT_TRUE(s->delete_chunk(b));
  ASSERT_TRUE(s->write_chunk(c, chunk_of(make_points(c, 2, 10))));
  // A reader in another connection sees the last checkpoint while this one is open.
  {
    auto reader = open_or_die(path, OpenMode::kReadOnly);
    ASSERT_TRUE(reader);
    auto ra = reader->read_chunk(a);
    ASSERT_TRUE(ra);
    EXPECT_TRUE(bit_equal(ra->chunk.points(), make_points(a, 1, 100)));
    EXPECT_TRUE(reader->read_chunk(b));
    EXPECT_EQ(reader->read_chunk(c).status().code(), StatusCode::kNotFound);
  }
  // A write that fails mid-checkpoint: the caller rolls back.
  PointArrays broken = make_points(c, 3, 5);
  broken.state.pop_back();
  EXPECT_EQ(s->write_chunk(c, chunk_of(broken)).code(), StatusCode::kInvalidArgument);
  s->rollback_checkpoint();
  s.reset();

  s = open_or_die(path, OpenMode::kReadOnly);
  auto ra = s->read_chunk(a);
  ASSERT_TRUE(ra);
  EXPECT_TRUE(bit_equal(ra->chunk.points(), make_points(a, 1, 100)));
  EXPECT_TRUE(s->read_chunk(b));
  EXPECT_EQ(s->read_chunk(c).status().code(), StatusCode::kNotFound);
  auto cps = s->checkpoints();
  ASSERT_TRUE(cps);
  EXPECT_EQ(cps->size(), 1u);
}

TEST(ScanStore, ReadSnapshotIsStableWhileTheWriterCommits) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  const ChunkKey a{0, 0, 0}, b{0, 1, 0};
  auto w = open_or_die(path, OpenMode::kCreate);
  ASSERT_TRUE(w);
  checkpoint(*w, {{a, make_points(a, 1, 100)}}, 1);
  auto r = open_or_die(path, OpenMode::kReadOnly);
  ASSERT_TRUE(r);
  {
    ScopedRead snapshot(*r);
    ASSERT_TRUE(snapshot.status());
    checkpoint(*w, {{a, make_points(a, 2, 90)}, {b, make_points(b, 2, 30)}}, 2);
    // The writer committed; the snapshot still shows checkpoint 1 throughout.
    auto list = r->list_chunks();
    ASSERT_TRUE(list);
    EXPECT_EQ(list->size(), 1u);
    auto ra = r->read_chunk(a);
    ASSERT_TRUE(ra);
    EXPECT_TRUE(bit_equal(ra->chunk.points(), make_points(a, 1, 100)));
  }
  auto list = r->list_chunks();
  ASSERT_TRUE(list);
  EXPECT_EQ(list->size(), 2u);
}

TEST(ScanStore, StagedChunksArePromotedByACheckpointAndDroppedAfterACrash) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  const ChunkKey a{0, 0, 0}, d{5, 5, 5}, e{6, 6, 6};
  {
    auto s = open_or_die(path, OpenMode::kCreate);
    ASSERT_TRUE(s);
    checkpoint(*s, {{a, make_points(a, 1, 100)}}, 10);
    Chunk cd = chunk_of(make_points(d, 1, 40));
    ASSERT_TRUE(s->stage_chunks({{d, &cd}}));
    auto staged = s->read_chunk(d, /*include_staged=*/true);
    ASSERT_TRUE(staged);
    EXPECT_TRUE(bit_equal(staged->chunk.points(), cd.points()));
    EXPECT_EQ(s->read_chunk(d).status().code(), StatusCode::kNotFound);  // not committed yet
    // Staging a chunk over a committed one, and an emptied chunk (a deletion).
    Chunk ca = chunk_of(make_points(a, 2, 70));
    ASSERT_TRUE(s->stage_chunks({{a, &ca}}));
    checkpoint(*s, {}, 20);
    auto promoted = s->read_chunk(d);
    ASSERT_TRUE(promoted);
    EXPECT_TRUE(bit_equal(promoted->chunk.points(), cd.points()));
    EXPECT_TRUE(bit_equal(s->read_chunk(a)->chunk.points(), ca.points()));
    Chunk empty;
    ASSERT_TRUE(s->stage_chunks({{a, &empty}}));
    checkpoint(*s, {}, 30);
    EXPECT_EQ(s->read_chunk(a).status().code(), StatusCode::kNotFound);

    // Work after the last checkpoint: a staged chunk, a keyframe; then the process "dies".
    Chunk ce = chunk_of(make_points(e, 1, 40));
    ASSERT_TRUE(s->stage_chunks({{e, &ce}}));
    ASSERT_TRUE(s->write_keyframe(some_keyframe(31)));
    ASSERT_TRUE(s->write_keyframe(some_keyframe(30)));
    EXPECT_FALSE(s->begin_checkpoint() && s->stage_chunks({{e, &ce}}));  // not inside a checkpoint
    s->rollback_checkpoint();
  }
  {
    // A reader does not see work after the last checkpoint.
    auto r = open_or_die(path, OpenMode::kReadOnly);
    auto kfs = r->list_keyframes();
    ASSERT_TRUE(kfs);
    ASSERT_EQ(kfs->size(), 1u);
    EXPECT_EQ((*kfs)[0].frame_id, 30u);
  }
  auto s = open_or_die(path, OpenMode::kReadWrite);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->open_report().discarded_staged_chunks, 1u);
  EXPECT_EQ(s->open_report().discarded_keyframes, 1u);
  EXPECT_EQ(s->read_chunk(e, true).status().code(), StatusCode::kNotFound);
  EXPECT_TRUE(s->read_keyframe(30));
  EXPECT_EQ(s->read_keyframe(31).status().code(), StatusCode::kNotFound);
}

// A checkpoint written in the background holds the map as of an earlier frame F: chunks staged
// by frames after F are neither promoted nor replaced by it (a crash discards them), those of its
// frames are promoted.
TEST(ScanStore, ACheckpointOfAnEarlierFrameLeavesLaterStagedChunksStaged) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  const ChunkKey a{1, 0, 0}, b{2, 0, 0};
  const Chunk a_staged = chunk_of(make_points(a, 1, 30), 15);
  const Chunk b_at_20 = chunk_of(make_points(b, 2, 40), 18), b_staged = chunk_of(make_points(b, 3, 50), 25);
  {
    auto s = open_or_die(path, OpenMode::kCreate);
    ASSERT_TRUE(s);
    checkpoint(*s, {}, 10);
    ASSERT_TRUE(s->stage_chunks({{a, &a_staged}, {b, &b_staged}}));
    ASSERT_TRUE(s->begin_checkpoint(20));
    ASSERT_TRUE(s->write_chunk(b, b_at_20));
    CheckpointInfo info;
    info.last_frame_id = 20;
    ASSERT_TRUE(s->commit_checkpoint(info));
    EXPECT_TRUE(bit_equal(s->read_chunk(a)->chunk.points(), a_staged.points()));   // promoted
    EXPECT_TRUE(bit_equal(s->read_chunk(b)->chunk.points(), b_at_20.points()));    // as of frame 20
    EXPECT_TRUE(bit_equal(s->read_chunk(b, true)->chunk.points(), b_staged.points()));  // still staged
    // The process dies before the next checkpoint.
  }
  auto s = open_or_die(path, OpenMode::kReadWrite);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->open_report().discarded_staged_chunks, 1u);
  EXPECT_TRUE(bit_equal(s->read_chunk(b, true)->chunk.points(), b_at_20.points()));
  EXPECT_TRUE(bit_equal(s->read_chunk(a)->chunk.points(), a_staged.points()));
}

TEST(ScanStore, OneWriterAtATime) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  auto w = open_or_die(path, OpenMode::kCreate);
  ASSERT_TRUE(w);
  auto second = ScanStore::open(path, OpenMode::kReadWrite);
  ASSERT_FALSE(second);
  EXPECT_EQ(second.status().code(), StatusCode::kUnavailable);
  EXPECT_NE(second.status().message().find("another process is writing"), std::string::npos);
  EXPECT_TRUE(ScanStore::open(path, OpenMode::kReadOnly));  // readers are welcome
  auto again = ScanStore::open(path, OpenMode::kCreate);
  ASSERT_FALSE(again);
  EXPECT_NE(again.status().message().find("already exists"), std::string::npos);
  w.reset();
  EXPECT_TRUE(ScanStore::open(path, OpenMode::kReadWrite));
}

namespace {

void sql(sqlite3* db, const std::string& text) {
  char* err = nullptr;
  ASSERT_EQ(sqlite3_exec(db, text.c_str(), nullptr, nullptr, &err), SQLITE_OK) << (err ? err : "");
}

// A scan file as schema 1 wrote it: no checkpoints table (the last checkpoint lived in meta keys),
// no staging, poses without ICP results, keyframes without colour.
void write_schema1_file(const std::string& path, const PointArrays& points, const ChunkKey& key) {
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  sql(db, "PRAGMA journal_mode = WAL;");
  sql(db, R"sql(
BEGIN;
CREATE TABLE meta (key TEXT PRIMARY KEY NOT NULL, value TEXT NOT NULL);
CREATE TABLE chunks (
  x INTEGER NOT NULL, y INTEGER NOT NULL, z INTEGER NOT NULL,
  point_count INTEGER NOT NULL,
  min_x REAL, min_y REAL, min_z REAL, max_x REAL, max_y REAL, max_z REAL,
  last_touched_frame INTEGER NOT NULL,
  data BLOB NOT NULL,
  PRIMARY KEY (x, y, z));
CREATE TABLE poses (frame_id INTEGER PRIMARY KEY, utime INTEGER NOT NULL, T_world_cam BLOB NOT NULL);
CREATE TABLE keyframes (
  frame_id INTEGER PRIMARY KEY, utime INTEGER NOT NULL, sensor_serial TEXT NOT NULL DEFAULT '',
  width INTEGER NOT NULL, height INTEGER NOT NULL,
  fx REAL NOT NULL, fy REAL NOT NULL, cx REAL NOT NULL, cy REAL NOT NULL,
  T_world_cam BLOB NOT NULL, depth BLOB NOT NULL);
INSERT INTO meta VALUES ('scan_id', 'old-scan'), ('created_utime', '1600000000000000'),
  ('chunk_size_m', '0.5'), ('method', 'full'),
  ('checkpoint_count', '3'), ('checkpoint_utime', '1600000000500000'),
  ('checkpoint_last_frame_id', '20');
PRAGMA application_id = 1145459523;
PRAGMA user_version = 1;
COMMIT;
)sql");
  BlobCodec codec;
  std::vector<uint8_t> blob;
  ASSERT_TRUE(codec.encode_points(points, &blob));
  sqlite3_stmt* st = nullptr;
  ASSERT_EQ(sqlite3_prepare_v2(db,
                               "INSERT INTO chunks VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, 19, ?);",
                               -1, &st, nullptr),
            SQLITE_OK);
  Eigen::AlignedBox3f box;
  for (size_t i = 0; i < points.size(); ++i) box.extend(points.position(i));
  sqlite3_bind_int(st, 1, key.x);
  sqlite3_bind_int(st, 2, key.y);
  sqlite3_bind_int(st, 3, key.z);
  sqlite3_bind_int64(st, 4, static_cast<int64_t>(points.size()));
  for (int a = 0; a < 3; ++a) {
    sqlite3_bind_double(st, 5 + a, box.min()[a]);
    sqlite3_bind_double(st, 8 + a, box.max()[a]);
  }
  sqlite3_bind_blob(st, 11, blob.data(), static_cast<int>(blob.size()), SQLITE_STATIC);
  ASSERT_EQ(sqlite3_step(st), SQLITE_DONE);
  sqlite3_finalize(st);
  for (int f = 1; f <= 20; ++f) {
    const auto pose = encode_pose(some_pose(f * 0.1));
    ASSERT_EQ(sqlite3_prepare_v2(db, "INSERT INTO poses VALUES (?, ?, ?);", -1, &st, nullptr), SQLITE_OK);
    sqlite3_bind_int(st, 1, f);
    sqlite3_bind_int64(st, 2, 1000 + f);
    sqlite3_bind_blob(st, 3, pose.data(), static_cast<int>(pose.size()), SQLITE_TRANSIENT);
    ASSERT_EQ(sqlite3_step(st), SQLITE_DONE);
    sqlite3_finalize(st);
  }
  const Keyframe k = some_keyframe(20);
  std::vector<uint8_t> depth;
  ASSERT_TRUE(codec.encode_depth(k.depth, &depth));
  const auto pose = encode_pose(k.T_world_cam);
  ASSERT_EQ(sqlite3_prepare_v2(db, "INSERT INTO keyframes VALUES (20, 1020, '014845', ?, ?, ?, ?, ?, ?, ?, ?);",
                               -1, &st, nullptr),
            SQLITE_OK);
  sqlite3_bind_int(st, 1, k.intrinsics.width);
  sqlite3_bind_int(st, 2, k.intrinsics.height);
  sqlite3_bind_double(st, 3, k.intrinsics.fx);
  sqlite3_bind_double(st, 4, k.intrinsics.fy);
  sqlite3_bind_double(st, 5, k.intrinsics.cx);
  sqlite3_bind_double(st, 6, k.intrinsics.cy);
  sqlite3_bind_blob(st, 7, pose.data(), static_cast<int>(pose.size()), SQLITE_TRANSIENT);
  sqlite3_bind_blob(st, 8, depth.data(), static_cast<int>(depth.size()), SQLITE_TRANSIENT);
  ASSERT_EQ(sqlite3_step(st), SQLITE_DONE);
  sqlite3_finalize(st);
  sqlite3_close(db);
}

}  // namespace

TEST(ScanStore, MigratesASchema1File) {
  TempDir dir;
  const std::string path = dir.file("old.db");
  const ChunkKey key{0, 0, 0};
  const PointArrays points = make_points(key, 1, 77);
  write_schema1_file(path, points, key);

  // Read-only cannot migrate and says how.
  auto ro = ScanStore::open(path, OpenMode::kReadOnly);
  ASSERT_FALSE(ro);
  EXPECT_EQ(ro.status().code(), StatusCode::kUnsupported);
  EXPECT_NE(ro.status().message().find("schema version 1"), std::string::npos) << ro.status().message();
  EXPECT_NE(ro.status().message().find("--upgrade"), std::string::npos) << ro.status().message();

  const std::string copy = dir.file("old-copy.db");
  std::filesystem::copy_file(path, copy);
  {
    auto s = open_or_die(path, OpenMode::kReadWrite);
    ASSERT_TRUE(s);
    EXPECT_TRUE(s->open_report().migrated);
    EXPECT_EQ(s->open_report().found_schema_version, 1);
    EXPECT_EQ(s->schema_version(), kSchemaVersion);
    // Poses of an older schema have no checksum: checked as far as they can be, and said so.
    auto integrity = s->integrity_check();
    ASSERT_TRUE(integrity);
    EXPECT_TRUE(integrity->ok());
    EXPECT_EQ(integrity->poses_checked, 20u);
    EXPECT_EQ(integrity->poses_unchecked, 20u);
    EXPECT_EQ(integrity->keyframes_unchecked, 1u);
    EXPECT_EQ(integrity->checkpoints_unchecked, 1u);
  }
  // The same through the CLI: inspect refuses, inspect --upgrade migrates and checks.
  const std::string cli = DEPTHFUSE_CLI;
  EXPECT_NE(std::system((cli + " inspect " + copy + " > /dev/null 2>&1").c_str()), 0);
  EXPECT_EQ(std::system((cli + " inspect --upgrade " + copy + " > /dev/null 2>&1").c_str()), 0);
  EXPECT_EQ(std::system((cli + " inspect " + copy + " > /dev/null 2>&1").c_str()), 0);
  EXPECT_EQ(std::system((cli + " inspect " + copy + " | grep -q '0 pose records checksummed, 20 "
                         "unchecked'").c_str()), 0);
  auto s = open_or_die(path, OpenMode::kReadOnly);
  ASSERT_TRUE(s);
  auto c = s->read_chunk(key);
  ASSERT_TRUE(c) << c.status().to_string();
  EXPECT_TRUE(bit_equal(c->chunk.points(), points));
  EXPECT_EQ(c->info.checkpoint_id, 3);
  EXPECT_EQ(c->chunk.last_touched_frame, 19u);
  auto last = s->last_checkpoint();
  ASSERT_TRUE(last && last->has_value());
  EXPECT_EQ((*last)->id, 3);
  EXPECT_EQ((*last)->last_frame_id, 20u);
  EXPECT_EQ((*last)->utime, 1600000000500000);
  EXPECT_EQ((*last)->point_count, 77u);
  EXPECT_EQ((*last)->reason, "migrated from schema 1");
  ASSERT_TRUE((*last)->T_world_cam);
  expect_same_pose(*(*last)->T_world_cam, some_pose(2.0));
  auto poses = s->read_poses();
  ASSERT_TRUE(poses);
  ASSERT_EQ(poses->size(), 20u);
  EXPECT_FALSE((*poses)[0].registered);
  auto kf = s->read_keyframe(20);
  ASSERT_TRUE(kf) << kf.status().to_string();
  EXPECT_TRUE(kf->color.empty());
  EXPECT_TRUE(test::same_bits(kf->depth.depth_m, some_keyframe(20).depth.depth_m));
  auto m = s->metadata();
  ASSERT_TRUE(m);
  EXPECT_EQ(m->scan_id, "old-scan");
  auto integrity = s->integrity_check();
  ASSERT_TRUE(integrity);
  EXPECT_TRUE(integrity->ok()) << integrity->problems.front();
  s.reset();
  // The migrated file takes new checkpoints, and a second open has nothing to migrate.
  auto w = open_or_die(path, OpenMode::kReadWrite);
  ASSERT_TRUE(w);
  EXPECT_FALSE(w->open_report().migrated);
  auto rec = checkpoint(*w, {{{1, 0, 0}, make_points({1, 0, 0}, 4, 10)}}, 21);
  EXPECT_EQ(rec.id, 4);
  EXPECT_EQ(rec.point_count, 87u);
}

// The poses stored with keyframes and checkpoints carry a checksum like pose rows: a pose changed
// in the file (still a valid pose: x 0.6 -> 1.2 m) is refused where it is read, and inspect finds
// it. Refining a keyframe's pose writes a new checksum.
TEST(ScanStore, KeyframeAndCheckpointPosesAreChecksummed) {
  TempDir dir;
  const std::string path = dir.file("s.db");
  {
    auto s = open_or_die(path, OpenMode::kCreate);
    ASSERT_TRUE(s);
    ASSERT_TRUE(s->write_keyframe(some_keyframe(1)));
    ASSERT_TRUE(s->begin_checkpoint());
    PoseRecord p;
    p.frame_id = 1;
    p.T_world_cam = some_pose(0.6);
    ASSERT_TRUE(s->write_pose(p));
    CheckpointInfo info;
    info.last_frame_id = 1;
    info.frames_fused = 1;
    info.T_world_cam = some_pose(0.6);
    ASSERT_TRUE(s->commit_checkpoint(info));
    ASSERT_TRUE(s->update_keyframe_pose(1, some_pose(0.7)));
    auto k = s->read_keyframe(1);
    ASSERT_TRUE(k) << k.status().to_string();
    expect_same_pose(k->T_world_cam, some_pose(0.7));
    auto integrity = s->integrity_check();
    ASSERT_TRUE(integrity);
    EXPECT_TRUE(integrity->ok());
    EXPECT_EQ(integrity->keyframes_unchecked + integrity->checkpoints_unchecked, 0u);
  }
  Pose moved = some_pose(0.6);
  moved.translation().x() += 0.6;
  const std::vector<uint8_t> blob = encode_pose(moved);
  for (const char* table : {"keyframes", "checkpoints"}) {
    SCOPED_TRACE(table);
    const std::string bad = dir.file(std::string(table) + ".db");
    std::filesystem::copy_file(path, bad);
    sqlite3* db = nullptr;
    ASSERT_EQ(sqlite3_open(bad.c_str(), &db), SQLITE_OK);
    sqlite3_stmt* st = nullptr;
    ASSERT_EQ(sqlite3_prepare_v2(db, (std::string("UPDATE ") + table + " SET T_world_cam = ?;").c_str(),
                                 -1, &st, nullptr),
              SQLITE_OK);
    sqlite3_bind_blob(st, 1, blob.data(), static_cast<int>(blob.size()), SQLITE_TRANSIENT);
    ASSERT_EQ(sqlite3_step(st), SQLITE_DONE);
    sqlite3_finalize(st);
    sqlite3_close(db);
    auto s = open_or_die(bad, OpenMode::kReadOnly);
    ASSERT_TRUE(s);
    if (std::string(table) == "keyframes") {
      auto k = s->read_keyframe(1);
      ASSERT_FALSE(k);
      EXPECT_EQ(k.status().code(), StatusCode::kCorrupt);
      EXPECT_NE(k.status().message().find("keyframe 1: checksum mismatch"), std::string::npos)
          << k.status().message();
      EXPECT_FALSE(s->list_keyframes());
    } else {
      auto last = s->last_checkpoint();
      ASSERT_FALSE(last);
      EXPECT_NE(last.status().message().find("checkpoint 1: checksum mismatch"), std::string::npos)
          << last.status().message();
    }
    auto integrity = s->integrity_check();
    ASSERT_TRUE(integrity);
    EXPECT_FALSE(integrity->ok());
  }
}

// Stored frame numbers that disagree are problems for inspect, and a writer does not resume them.
TEST(ScanStore, FrameNumbersThatDisagreeAreNotResumed) {
  TempDir dir;
  const std::string good = dir.file("good.db");
  {
    auto s = open_or_die(good, OpenMode::kCreate);
    ASSERT_TRUE(s);
    ASSERT_TRUE(s->begin_checkpoint());
    for (uint32_t f = 1; f <= 12; ++f) {
      PoseRecord p;
      p.frame_id = f;
      p.T_world_cam = some_pose(f * 0.1);
      ASSERT_TRUE(s->write_pose(p));
    }
    CheckpointInfo info;
    info.last_frame_id = 12;
    info.frames_fused = 12;
    ASSERT_TRUE(s->commit_checkpoint(info));
  }
  struct Case {
    const char* damage;
    const char* expect;
  };
  // The rows are changed as a writer without checksums (before schema 4) would have written them:
  // with its checksum, the changed row is refused as damaged before its numbers are looked at.
  for (const Case& c : {
           Case{"UPDATE checkpoints SET last_frame_id = 40, checksum = NULL;", "holds frames up to 40 but the newest pose is of frame 12"},
           Case{"UPDATE checkpoints SET last_frame_id = 4294967295, checksum = NULL;", "last frame id 4294967295 is out of range"},
           Case{"UPDATE checkpoints SET frames_fused = 5, checksum = NULL;", "counts 5 frames fused but the file holds 12 poses"},
           Case{"INSERT INTO checkpoints SELECT 2, utime, reason, 3, frames_fused, point_count, chunk_count, "
                "T_world_cam, NULL FROM checkpoints WHERE id = 1;",
                "checkpoint 2 holds frames up to 3, fewer than checkpoint 1 before it (12)"},
           Case{"UPDATE checkpoints SET frames_fused = 5;", "checkpoint 1: checksum mismatch"},
       }) {
    SCOPED_TRACE(c.damage);
    const std::string path = dir.file("bad.db");
    std::filesystem::remove(path);
    std::filesystem::copy_file(good, path);
    sqlite3* db = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
    sql(db, c.damage);
    sqlite3_close(db);
    ResumePoint at;
    auto resumed = ScanRecorder::resume(path, RecorderConfig{}, &at);
    ASSERT_FALSE(resumed);
    EXPECT_EQ(resumed.status().code(), StatusCode::kCorrupt);
    EXPECT_NE(resumed.status().message().find(c.expect), std::string::npos) << resumed.status().message();
    auto r = open_or_die(path, OpenMode::kReadOnly);
    ASSERT_TRUE(r);
    auto integrity = r->integrity_check(/*check_blobs=*/false);
    ASSERT_TRUE(integrity);
    ASSERT_FALSE(integrity->ok());
    EXPECT_NE(integrity->problems[0].find(c.expect), std::string::npos) << integrity->problems[0];
  }
  ResumePoint at;
  auto resumed = ScanRecorder::resume(good, RecorderConfig{}, &at);
  ASSERT_TRUE(resumed) << resumed.status().to_string();
  EXPECT_EQ(at.next_frame_id, 13u);
}

TEST(ScanStore, RejectsForeignAndNewerFiles) {
  TempDir dir;
  const std::string foreign = dir.file("foreign.db"), newer = dir.file("newer.db");
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(foreign.c_str(), &db), SQLITE_OK);
  sql(db, "CREATE TABLE t (a); INSERT INTO t VALUES (1);");
  sqlite3_close(db);
  auto f = ScanStore::open(foreign, OpenMode::kReadOnly);
  ASSERT_FALSE(f);
  EXPECT_NE(f.status().message().find("not a depthfuse scan"), std::string::npos) << f.status().message();

  { auto s = open_or_die(newer, OpenMode::kCreate); }
  ASSERT_EQ(sqlite3_open(newer.c_str(), &db), SQLITE_OK);
  sql(db, "PRAGMA user_version = 99;");
  sqlite3_close(db);
  auto n = ScanStore::open(newer, OpenMode::kReadWrite);
  ASSERT_FALSE(n);
  EXPECT_EQ(n.status().code(), StatusCode::kUnsupported);
  EXPECT_NE(n.status().message().find("newer depthfuse"), std::string::npos) << n.status().message();
}

namespace {

// A closed scan file with enough chunks to span many pages.
void make_scan(const std::string& path, int chunks, size_t points_each = 400) {
  auto s = open_or_die(path, OpenMode::kCreate);
  ASSERT_TRUE(s);
  std::vector<std::pair<ChunkKey, PointArrays>> list;
  for (int i = 0; i < chunks; ++i) {
    const ChunkKey k{i, -i, i % 4};
    list.emplace_back(k, make_points(k, 1, points_each));
  }
  checkpoint(*s, list, 5);
}

std::vector<long> blob_offsets(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::vector<long> out;
  for (size_t p = bytes.find("DFB1"); p != std::string::npos; p = bytes.find("DFB1", p + 1)) out.push_back(static_cast<long>(p));
  return out;
}

}  // namespace

TEST(ScanStore, GarbageEmptyAndTruncatedFilesGetClearErrors) {
  TempDir dir;
  const std::string garbage = dir.file("garbage.db"), empty = dir.file("empty.db"), cut = dir.file("cut.db");
  {
    std::ofstream g(garbage, std::ios::binary);
    std::mt19937 rng(1);
    for (int i = 0; i < 100000; ++i) g.put(static_cast<char>(rng()));
    std::ofstream e(empty);
  }
  auto g = ScanStore::open(garbage, OpenMode::kReadOnly);
  ASSERT_FALSE(g);
  EXPECT_EQ(g.status().code(), StatusCode::kCorrupt);
  EXPECT_NE(g.status().message().find("not a scan file"), std::string::npos) << g.status().message();
  auto e = ScanStore::open(empty, OpenMode::kReadWrite);
  ASSERT_FALSE(e);
  EXPECT_NE(e.status().message().find("empty"), std::string::npos) << e.status().message();
  auto missing = ScanStore::open(dir.file("missing.db"), OpenMode::kReadOnly);
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);

  make_scan(cut, 200);
  const auto size = std::filesystem::file_size(cut);
  std::filesystem::resize_file(cut, size / 2);
  auto t = ScanStore::open(cut, OpenMode::kReadOnly);
  ASSERT_FALSE(t);
  EXPECT_EQ(t.status().code(), StatusCode::kCorrupt);
  EXPECT_NE(t.status().message().find("truncated"), std::string::npos) << t.status().message();
}

TEST(ScanStore, AFlippedByteInABlobIsFoundAndNamed) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  make_scan(path, 30);
  const auto offsets = blob_offsets(path);
  ASSERT_GE(offsets.size(), 30u);
  test::flip_byte(path, offsets[7] + 300);  // inside the compressed payload of one chunk

  auto s = open_or_die(path, OpenMode::kReadOnly);
  ASSERT_TRUE(s);
  auto integrity = s->integrity_check();
  ASSERT_TRUE(integrity);
  ASSERT_EQ(integrity->problems.size(), 1u);
  EXPECT_NE(integrity->problems[0].find("chunk ("), std::string::npos) << integrity->problems[0];
  // Iteration stops at the damaged chunk with the same message...
  Status st = s->for_each_chunk([](const ChunkInfo&, PointArrays&) { return Status::ok(); });
  EXPECT_EQ(st.code(), StatusCode::kCorrupt);
  EXPECT_EQ(st.message(), integrity->problems[0]);
  // ... or skips it when salvaging.
  size_t visited = 0, damaged = 0;
  ChunkFilter salvage;
  salvage.on_damaged = [&](const Status&) { ++damaged; };
  ASSERT_TRUE(s->for_each_chunk([&](const ChunkInfo&, PointArrays&) { ++visited; return Status::ok(); }, salvage));
  EXPECT_EQ(visited, 29u);
  EXPECT_EQ(damaged, 1u);
}

TEST(ScanStore, RandomDamageNeverCrashes) {
  TempDir dir;
  const std::string clean = dir.file("clean.db");
  make_scan(clean, 40, 200);
  const auto size = static_cast<long>(std::filesystem::file_size(clean));
  std::mt19937 rng(42);
  int opened = 0, detected = 0;
  for (int round = 0; round < 60; ++round) {
    const std::string path = dir.file("damaged-" + std::to_string(round) + ".db");
    std::filesystem::copy_file(clean, path);
    // A burst of damage somewhere (page headers, b-tree cells, blobs, the file header).
    const long at = static_cast<long>(rng() % static_cast<uint32_t>(size - 64));
    for (int i = 0; i < 16; ++i) test::flip_byte(path, at + i * 3);
    auto s = ScanStore::open(path, OpenMode::kReadOnly);
    if (!s) {
      ++detected;
      EXPECT_FALSE(s.status().message().empty());
      continue;
    }
    ++opened;
    auto sum = (*s)->summary();
    auto integrity = (*s)->integrity_check();
    Status it = (*s)->for_each_chunk([](const ChunkInfo&, PointArrays&) { return Status::ok(); });
    if (!sum || !it || !integrity || !integrity->ok()) ++detected;
    std::filesystem::remove(path);
  }
  // Most bursts land in blob payloads or b-tree pages, and they are reported.
  EXPECT_GT(detected, 40) << opened << " opened";
}

// Issue 36: a pose row of a schema-5 file whose checksum was set to NULL and whose pose was moved
// passed `inspect` as "written before schema 3". Only rows older than the checksum column (what
// the migration recorded, here none) may lack one: a later row without one is damage, for poses,
// keyframes and checkpoints alike. The file is edited by the sqlite3 program; the check is the
// CLI's.
TEST(ScanStore, ANullChecksumInARowThatMustHaveOneIsDamage) {
  TempDir dir;
  const std::string path = dir.file("s.db");
  {
    auto s = open_or_die(path, OpenMode::kCreate);
    ASSERT_TRUE(s);
    for (uint32_t id : {1u, 2u}) ASSERT_TRUE(s->write_keyframe(some_keyframe(id)));
    for (uint32_t last : {2u, 3u}) {
      ASSERT_TRUE(s->begin_checkpoint());
      for (uint32_t id = last - 1; id <= last; ++id) {
        PoseRecord p;
        p.frame_id = id;
        p.T_world_cam = some_pose(0.1 * id);
        ASSERT_TRUE(s->write_pose(p));
      }
      CheckpointInfo info;
      info.last_frame_id = last;
      info.frames_fused = last;
      info.T_world_cam = some_pose(0.1 * last);
      ASSERT_TRUE(s->commit_checkpoint(info));
    }
  }
  const std::string cli = DEPTHFUSE_CLI;
  auto run = [&](const std::string& command, std::string* out) {
    const std::string log = dir.file("out.txt");
    const int rc = std::system((command + " > " + log + " 2>&1").c_str());
    std::ifstream in(log);
    out->assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
  };
  std::string out;
  ASSERT_EQ(run(cli + " inspect " + path, &out), 0) << out;

  struct Case {
    const char* what;
    const char* sql;
    const char* says;
  };
  const Case cases[] = {
      {"a pose moved, its checksum cleared",
       "UPDATE poses SET checksum = NULL, T_world_cam = (SELECT T_world_cam FROM poses WHERE "
       "frame_id = 1) WHERE frame_id = 2;",
       "pose of frame 2 has no checksum, though every pose from frame 1 on carries one "
       "(schema 3): the row was altered or damaged"},
      {"a keyframe's checksum cleared", "UPDATE keyframes SET checksum = NULL WHERE frame_id = 2;",
       "keyframe 2 has no checksum, though every keyframe from frame 1 on carries one (schema 4)"},
      {"a checkpoint's checksum cleared", "UPDATE checkpoints SET checksum = NULL WHERE id = 1;",
       "checkpoint 1 has no checksum, though every checkpoint from id 1 on carries one"},
      // A file from before the migrations recorded where checksums start: the first row that
      // has one says it.
      {"the same pose in a file that does not record where checksums start",
       "DELETE FROM meta WHERE key LIKE '%checksums_from%'; UPDATE poses SET checksum = NULL "
       "WHERE frame_id = 2;",
       "pose of frame 2 has no checksum, though every pose from frame 1 on carries one"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.what);
    const std::string bad = dir.file("bad.db");
    std::filesystem::remove(bad);
    std::filesystem::copy_file(path, bad);
    ASSERT_EQ(run("sqlite3 " + bad + " \"" + c.sql + "\"", &out), 0) << out;
    EXPECT_EQ(run(cli + " inspect " + bad, &out), 1) << out;
    EXPECT_NE(out.find(bad + ": " + c.says), std::string::npos) << out;
  }
  // Rows older than the checksum (here: as a migration from schema 2 would have recorded it) are
  // unchecked, not damage.
  const std::string old = dir.file("old.db");
  std::filesystem::copy_file(path, old);
  ASSERT_EQ(run("sqlite3 " + old + " \"UPDATE poses SET checksum = NULL WHERE frame_id <= 2; "
                "UPDATE meta SET value = '3' WHERE key = 'pose_checksums_from_frame';\"", &out),
            0)
      << out;
  EXPECT_EQ(run(cli + " inspect " + old, &out), 0) << out;
  EXPECT_NE(out.find("2 unchecked (written before schema 3"), std::string::npos) << out;
}

namespace {

// A graph of keyframes at `frames`, placed at `T_world_kf`, as a checkpoint writes it.
GraphCheckpoint graph_of(const std::vector<uint32_t>& frames, const std::vector<Pose>& T_world_kf,
                         uint32_t version) {
  GraphCheckpoint g;
  for (size_t k = 0; k < frames.size(); ++k) {
    GraphKeyframe kf;
    kf.frame_id = frames[k];
    kf.T_world_kf = T_world_kf[k];
    kf.cloud = std::make_shared<const KeyframeCloud>();
    g.graph.keyframes.push_back(kf);
    if (k > 0) {
      PoseGraphEdge odometry;
      odometry.T_from_to = T_world_kf[k - 1].inverse() * T_world_kf[k];
      g.graph.odometry.push_back(odometry);
      g.graph.odometry_covariance.push_back(Matrix6d::Identity());
    }
  }
  g.graph.version = version;
  g.deformation.keyframe_first_frame = frames;
  g.deformation.oldest_version = version;
  g.deformation.T_world_kf = {T_world_kf};
  g.deformation.max_motion_m = {0.0};
  return g;
}

// The stored rows of the poses table, as bytes: frame id -> (pose blob, anchor, checksum).
std::map<int64_t, std::string> pose_rows(const std::string& path) {
  std::map<int64_t, std::string> rows;
  sqlite3* db = nullptr;
  EXPECT_EQ(sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr), SQLITE_OK);
  sqlite3_stmt* st = nullptr;
  EXPECT_EQ(sqlite3_prepare_v2(db, "SELECT frame_id, T_world_cam, quote(graph_keyframe), checksum "
                                   "FROM poses;", -1, &st, nullptr),
            SQLITE_OK);
  while (sqlite3_step(st) == SQLITE_ROW) {
    const auto* blob = static_cast<const char*>(sqlite3_column_blob(st, 1));
    std::string row(blob, static_cast<size_t>(sqlite3_column_bytes(st, 1)));
    row += "|" + std::string(reinterpret_cast<const char*>(sqlite3_column_text(st, 2))) + "|" +
           std::to_string(sqlite3_column_int64(st, 3));
    rows[sqlite3_column_int64(st, 0)] = row;
  }
  sqlite3_finalize(st);
  sqlite3_close(db);
  return rows;
}

double pose_error(const Pose& a, const Pose& b) { return (a.matrix() - b.matrix()).norm(); }

}  // namespace

// A loop closure moves keyframes all over the scan. The stored poses follow the graph's keyframes
// (each relative to the keyframe of its segment), so a correction rewrites the graph's row, not
// every pose row of the scan: that rewrite grew with the scan and held the file for longer at
// every closure.
TEST(ScanStore, ACorrectionMovesTheStoredPosesWithoutRewritingTheirRows) {
  TempDir dir;
  const std::string path = dir.file("anchored.db");
  std::vector<Pose> W(22);
  for (uint32_t f = 1; f <= 21; ++f) W[f] = some_pose(f * 0.1);
  auto s = ScanStore::open(path, OpenMode::kCreate);
  ASSERT_TRUE(s) << s.status().to_string();
  auto checkpoint = [&](uint32_t first, uint32_t last, const std::vector<Pose>& fused,
                        const std::vector<PoseCorrection>& corrections, const GraphCheckpoint& g) {
    ASSERT_TRUE((*s)->begin_checkpoint());
    std::vector<PoseRecord> poses;
    for (uint32_t f = first; f <= last; ++f) {
      PoseRecord p;
      p.frame_id = f;
      p.utime = f;
      p.T_world_cam = fused[f];
      poses.push_back(p);
    }
    ASSERT_TRUE((*s)->write_poses(poses, corrections, g.graph.keyframes));
    ASSERT_TRUE((*s)->write_graph(g));
    CheckpointInfo info;
    info.last_frame_id = last;
    info.frames_fused = last;
    ASSERT_TRUE((*s)->commit_checkpoint(info));
  };
  // Frames 1..20, keyframes at frames 1 and 11.
  checkpoint(1, 20, W, {}, graph_of({1, 11}, {W[1], W[11]}, 0));
  const std::map<int64_t, std::string> before = pose_rows(path);
  auto poses = (*s)->read_poses();
  ASSERT_TRUE(poses) << poses.status().to_string();
  ASSERT_EQ(poses->size(), 20u);
  for (const PoseRecord& p : *poses) EXPECT_LT(pose_error(p.T_world_cam, W[p.frame_id]), 1e-12);

  // A correction moves keyframe 1 (frames 11 on) by M; frame 21 is fused after it.
  Pose M = Pose::Identity();
  M.translation() = Eigen::Vector3d(0.0, 0.1, 0.0);
  M.linear() = Eigen::AngleAxisd(0.02, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  PoseCorrection c;
  c.correction.first_frame_id = {1, 11};
  c.correction.motion = {Pose::Identity(), M};
  c.before_frame = 21;
  std::vector<Pose> fused = W;
  fused[21] = M * W[21];
  checkpoint(21, 21, fused, {c}, graph_of({1, 11}, {W[1], M * W[11]}, 1));

  std::map<int64_t, std::string> after = pose_rows(path);
  ASSERT_EQ(after.erase(21), 1u);
  EXPECT_TRUE(after == before) << "a stored pose row was rewritten by the correction";
  poses = (*s)->read_poses();
  ASSERT_TRUE(poses) << poses.status().to_string();
  ASSERT_EQ(poses->size(), 21u);
  for (const PoseRecord& p : *poses) {
    const Pose expected = p.frame_id < 11 ? W[p.frame_id] : Pose(M * W[p.frame_id]);
    EXPECT_LT(pose_error(p.T_world_cam, expected), 1e-9) << "frame " << p.frame_id;
  }
  auto integrity = (*s)->integrity_check();
  ASSERT_TRUE(integrity);
  EXPECT_TRUE(integrity->ok()) << integrity->problems.front();
}

// A file of schema 7 has no table of pending points (its checkpoints brought their chunks up to
// date first): a reader asks for the migration, a writer makes the table, and nothing is pending.
TEST(ScanStore, ASchemaSevenFileGetsAnEmptyTableOfPendingPoints) {
  TempDir dir;
  const std::string path = dir.file("v7.db");
  const ChunkKey a{0, 0, 0};
  {
    auto s = ScanStore::open(path, OpenMode::kCreate);
    ASSERT_TRUE(s);
    checkpoint(**s, {{a, make_points(a, 1, 100)}}, 10);
  }
  test::exec_sql(path, test::as_schema_7_sql());
  auto reader = ScanStore::open(path, OpenMode::kReadOnly);
  ASSERT_FALSE(reader);
  EXPECT_NE(reader.status().message().find("schema version 7 is older"), std::string::npos)
      << reader.status().message();
  auto s = ScanStore::open(path, OpenMode::kReadWrite);
  ASSERT_TRUE(s) << s.status().to_string();
  EXPECT_EQ((*s)->open_report().found_schema_version, 7);
  EXPECT_EQ((*s)->schema_version(), kSchemaVersion);
  auto pending = (*s)->read_pending();
  ASSERT_TRUE(pending) << pending.status().to_string();
  EXPECT_TRUE(pending->empty());
  auto chunk = (*s)->read_chunk(a);
  ASSERT_TRUE(chunk);
  EXPECT_EQ(chunk->chunk.points().size(), 100u);
  auto integrity = (*s)->integrity_check();
  ASSERT_TRUE(integrity);
  EXPECT_TRUE(integrity->ok()) << integrity->problems.front();
}

// A file of schema 6 stored every pose in the world frame and rewrote them at each correction.
// Migrated, its rows are anchored by the next checkpoint, the correction applied to them first.
TEST(ScanStore, ASchemaSixFileHasItsPosesAnchoredByTheNextCheckpoint) {
  TempDir dir;
  const std::string path = dir.file("v6.db");
  std::vector<Pose> W(12);
  for (uint32_t f = 1; f <= 11; ++f) W[f] = some_pose(f * 0.1);
  {
    auto s = ScanStore::open(path, OpenMode::kCreate);
    ASSERT_TRUE(s);
    ASSERT_TRUE((*s)->begin_checkpoint());
    for (uint32_t f = 1; f <= 10; ++f) {
      PoseRecord p;
      p.frame_id = f;
      p.T_world_cam = W[f];
      ASSERT_TRUE((*s)->write_pose(p));
    }
    CheckpointInfo info;
    info.last_frame_id = 10;
    ASSERT_TRUE((*s)->commit_checkpoint(info));
  }
  test::exec_sql(path, test::as_schema_6_sql());
  auto s = ScanStore::open(path, OpenMode::kReadWrite);
  ASSERT_TRUE(s) << s.status().to_string();
  EXPECT_EQ((*s)->open_report().found_schema_version, 6);
  Pose M = Pose::Identity();
  M.translation() = Eigen::Vector3d(0.2, 0.0, 0.0);
  PoseCorrection c;
  c.correction.first_frame_id = {1, 6};
  c.correction.motion = {Pose::Identity(), M};
  c.before_frame = 11;
  ASSERT_TRUE((*s)->begin_checkpoint());
  PoseRecord p;
  p.frame_id = 11;
  p.T_world_cam = M * W[11];
  const GraphCheckpoint g = graph_of({1, 6}, {W[1], M * W[6]}, 1);
  ASSERT_TRUE((*s)->write_poses({p}, {c}, g.graph.keyframes));
  ASSERT_TRUE((*s)->write_graph(g));
  CheckpointInfo info;
  info.last_frame_id = 11;
  ASSERT_TRUE((*s)->commit_checkpoint(info));
  for (const auto& [frame, row] : pose_rows(path))
    EXPECT_EQ(row.find("|NULL|"), std::string::npos) << "frame " << frame << " is not anchored";
  auto poses = (*s)->read_poses();
  ASSERT_TRUE(poses) << poses.status().to_string();
  ASSERT_EQ(poses->size(), 11u);
  for (const PoseRecord& r : *poses) {
    const Pose expected = r.frame_id < 6 ? W[r.frame_id] : Pose(M * W[r.frame_id]);
    EXPECT_LT(pose_error(r.T_world_cam, expected), 1e-9) << "frame " << r.frame_id;
  }
}

// A keyframe of a frame after the checkpoint's (written while a background checkpoint was in
// flight) may already be in a later graph version than the checkpoint's: anchored to the
// checkpoint's graph, a correction made before it was fused would move it a second time. It stays
// in the world frame for the checkpoint that holds its frame.
TEST(ScanStore, AKeyframeOfALaterFrameIsLeftForItsOwnCheckpoint) {
  TempDir dir;
  const std::string path = dir.file("later.db");
  auto s = ScanStore::open(path, OpenMode::kCreate);
  ASSERT_TRUE(s);
  ASSERT_TRUE((*s)->write_keyframe(some_keyframe(5)));
  ASSERT_TRUE((*s)->write_keyframe(some_keyframe(12)));
  ASSERT_TRUE((*s)->begin_checkpoint(10));
  const GraphCheckpoint g = graph_of({1}, {some_pose(0.1)}, 0);
  ASSERT_TRUE((*s)->write_poses({}, {}, g.graph.keyframes));
  ASSERT_TRUE((*s)->write_graph(g));
  CheckpointInfo info;
  info.last_frame_id = 10;
  ASSERT_TRUE((*s)->commit_checkpoint(info));
  std::string anchors;
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr), SQLITE_OK);
  sqlite3_stmt* st = nullptr;
  ASSERT_EQ(sqlite3_prepare_v2(db, "SELECT frame_id, quote(graph_keyframe) FROM keyframes "
                                   "ORDER BY frame_id;", -1, &st, nullptr),
            SQLITE_OK);
  while (sqlite3_step(st) == SQLITE_ROW)
    anchors += std::to_string(sqlite3_column_int64(st, 0)) + ":" +
               reinterpret_cast<const char*>(sqlite3_column_text(st, 1)) + " ";
  sqlite3_finalize(st);
  EXPECT_EQ(anchors, "5:0 12:NULL ");
  // The summary (`depthfuse inspect`) counts and sizes the checkpoint's keyframes only.
  ASSERT_EQ(sqlite3_prepare_v2(db, "SELECT length(depth) + COALESCE(length(color), 0) FROM keyframes "
                                   "WHERE frame_id = 5;", -1, &st, nullptr),
            SQLITE_OK);
  ASSERT_EQ(sqlite3_step(st), SQLITE_ROW);
  const sqlite3_int64 committed_bytes = sqlite3_column_int64(st, 0);
  sqlite3_finalize(st);
  sqlite3_close(db);
  auto sum = (*s)->summary();
  ASSERT_TRUE(sum) << sum.status().to_string();
  EXPECT_EQ(sum->keyframe_count, 1u);
  EXPECT_EQ(sum->keyframe_bytes, static_cast<uint64_t>(committed_bytes));
  auto k = (*s)->read_keyframe(5);
  ASSERT_TRUE(k) << k.status().to_string();
  EXPECT_LT(pose_error(k->T_world_cam, some_pose(0.5)), 1e-9);
}
