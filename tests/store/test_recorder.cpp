// ScanRecorder with the real incremental pipeline on an analytic corridor: a bounded-memory run
// gives exactly the cloud and poses of an unbounded run; a scan killed with SIGKILL again and
// again and resumed from its checkpoints ends exactly where an uninterrupted run ends.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <map>
#include <random>
#include <thread>

#include "depthfuse/pipeline.hpp"
#include "depthfuse/store/scan_recorder.hpp"
#include "store_test_util.hpp"

using namespace depthfuse;
using namespace depthfuse::store;
using test::bit_equal;
using test::ChunkContents;
using test::expect_same_cloud;
using test::TempDir;

namespace {

ReconstructionConfig config() {
  ReconstructionConfig c;
  c = c.with_method(Method::kFull);
  return c;
}

RecorderConfig recorder_config(double budget_mib) {
  RecorderConfig rc;
  rc.bounded_memory = true;
  rc.pager.memory_budget_mib = budget_mib;
  rc.pager.evict_distance_m = 1.0;
  rc.pager.min_age_frames = 5;
  rc.keyframe_every_n_frames = 5;
  return rc;
}

// The map's non-empty chunks.
ChunkContents map_contents(const PointMap& map) {
  ChunkContents out;
  map.for_each_chunk([&](const ChunkKey& k, const Chunk& c) {
    if (!c.points().empty()) out[k] = c.points();
  });
  return out;
}

void wait_for_background_checkpoint(const ScanRecorder& recorder) {
  while (recorder.checkpoint_in_flight()) std::this_thread::sleep_for(std::chrono::milliseconds(5));
}

// The scene and an uninterrupted, unbounded run over it (computed once).
struct Reference {
  std::vector<Frame> frames;
  std::vector<Pose> poses;
  ChunkContents cloud;  // after finish() (post-filter)
  double ms_per_frame = 0;
};

const Reference& reference() {
  static const Reference ref = [] {
    Reference r;
    test::Corridor corridor;
    corridor.length_m = 48.0;
    const int n = 300;
    for (int i = 0; i < n; ++i)
      r.frames.push_back(corridor.render(corridor.pose(i, n), test::small_camera(), static_cast<uint32_t>(i)));
    IncrementalReconstructor rec(config());
    const auto t0 = std::chrono::steady_clock::now();
    for (const Frame& f : r.frames) {
      auto rep = rec.process(f);
      if (!rep) std::abort();
      r.poses.push_back(rep->T_world_cam);
    }
    r.ms_per_frame = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() /
                     static_cast<double>(n);
    rec.finish();
    r.cloud = map_contents(rec.map());
    return r;
  }();
  return ref;
}

ChunkContents stored_cloud(const std::string& path) {
  ChunkContents out;
  auto s = ScanStore::open(path, OpenMode::kReadOnly);
  EXPECT_TRUE(s) << s.status().to_string();
  if (!s) return out;
  Status st = (*s)->for_each_chunk([&](const ChunkInfo& info, PointArrays& a) {
    out[info.key] = std::move(a);
    return Status::ok();
  });
  EXPECT_TRUE(st) << st.to_string();
  return out;
}

void expect_same_poses(const std::string& path, const std::vector<Pose>& want, size_t count) {
  auto s = ScanStore::open(path, OpenMode::kReadOnly);
  ASSERT_TRUE(s);
  auto poses = (*s)->read_poses();
  ASSERT_TRUE(poses);
  ASSERT_EQ(poses->size(), count);
  for (size_t i = 0; i < count; ++i) {
    EXPECT_EQ((*poses)[i].frame_id, i + 1);
    EXPECT_TRUE((*poses)[i].T_world_cam.isApprox(want[i], 0.0)) << "frame " << i + 1;
  }
}

ScanMetadata metadata() {
  ScanMetadata m;
  m.scan_id = "corridor";
  m.method = "full";
  m.chunk_size_m = config().fusion.chunk_size_m;
  return m;
}

}  // namespace

TEST(Recorder, BoundedRunEqualsUnboundedRun) {
  const Reference& ref = reference();
  size_t total_bytes = 0;
  for (const auto& [k, a] : ref.cloud) total_bytes += a.memory_bytes();
  TempDir dir;
  const std::string path = dir.file("scan.db");
  const double budget_mib = 8.0;
  auto made = ScanRecorder::create(path, metadata(), "[fusion]\n", "test", recorder_config(budget_mib));
  ASSERT_TRUE(made) << made.status().to_string();
  ScanRecorder& recorder = **made;
  IncrementalReconstructor rec(config());
  size_t max_resident = 0;
  for (size_t i = 0; i < ref.frames.size(); ++i) {
    ASSERT_TRUE(recorder.prepare_frame(ref.frames[i], rec.initial_pose(ref.frames[i], std::nullopt), rec)) << recorder.status().last_error;
    auto rep = rec.process(ref.frames[i]);
    ASSERT_TRUE(rep) << rep.status().to_string();
    ASSERT_TRUE(recorder.record_frame(ref.frames[i], *rep, &rec.map())) << recorder.status().last_error;
    max_resident = std::max(max_resident, recorder.status().pager.resident_bytes);
    EXPECT_EQ(recorder.status().pager.unevictable_bytes, 0u) << "frame " << i;
    if (i % 40 == 39) {
      ASSERT_TRUE(recorder.checkpoint(&rec.map(), "periodic"));
    }
  }
  rec.finish();
  auto fin = recorder.finish(&rec.map());
  ASSERT_TRUE(fin) << fin.status().to_string();
  const PagerStats& ps = recorder.status().pager;
  std::printf("cloud %.2f MiB in %zu chunks; budget %.2f MiB, max resident %.2f MiB; evicted %llu, loaded %llu\n",
              total_bytes / 1048576.0, ref.cloud.size(), budget_mib, max_resident / 1048576.0,
              static_cast<unsigned long long>(ps.total_evicted), static_cast<unsigned long long>(ps.total_loaded));
  EXPECT_GT(total_bytes, 2 * budget_mib * 1048576.0) << "the scene is too small to need the pager";
  EXPECT_LE(max_resident, budget_mib * 1048576.0);
  EXPECT_GT(ps.total_evicted, 0u);
  EXPECT_GT(ps.total_loaded, 0u);  // the walk comes back
  EXPECT_EQ(ps.load_collisions, 0u);
  expect_same_cloud(stored_cloud(path), ref.cloud);
  expect_same_poses(path, ref.poses, ref.frames.size());
  auto s = ScanStore::open(path, OpenMode::kReadOnly);
  ASSERT_TRUE(s);
  auto kfs = (*s)->list_keyframes();
  ASSERT_TRUE(kfs);
  EXPECT_EQ(kfs->size(), ref.frames.size() / 5);
  auto integrity = (*s)->integrity_check();
  ASSERT_TRUE(integrity);
  EXPECT_TRUE(integrity->ok());
}

namespace {

// One life of the scanning process: create or resume, fuse the remaining frames with a
// checkpoint every 5 frames, finish. Exits 0 when the scan is complete.
[[noreturn]] void scan_process(const std::string& path) {
  const Reference& ref = reference();
  std::unique_ptr<ScanRecorder> recorder;
  IncrementalReconstructor rec(config());
  size_t next = 0;
  if (access(path.c_str(), F_OK) != 0) {
    auto made = ScanRecorder::create(path, metadata(), "[fusion]\n", "test", recorder_config(8.0));
    if (!made) _exit(3);
    recorder = std::move(made).value();
  } else {
    ResumePoint resume;
    auto opened = ScanRecorder::resume(path, recorder_config(8.0), &resume);
    if (!opened) {
      std::fprintf(stderr, "resume: %s\n", opened.status().to_string().c_str());
      _exit(4);
    }
    recorder = std::move(opened).value();
    next = resume.next_frame_id - 1;
    rec.reset(std::move(resume.map), resume.next_frame_id, resume.last_T_world_cam);
  }
  for (size_t i = next; i < ref.frames.size(); ++i) {
    if (!recorder->prepare_frame(ref.frames[i], rec.initial_pose(ref.frames[i], std::nullopt), rec)) _exit(9);
    auto rep = rec.process(ref.frames[i]);
    if (!rep || rep->frame_id != i + 1) _exit(5);
    if (!recorder->record_frame(ref.frames[i], *rep, &rec.map())) _exit(6);
    if (i % 5 == 4 && !recorder->checkpoint(&rec.map(), "periodic")) _exit(7);
  }
  rec.finish();
  if (!recorder->finish(&rec.map())) _exit(8);
  _exit(0);
}

}  // namespace

TEST(Recorder, KilledAndResumedScanEqualsUninterruptedRun) {
  const Reference& ref = reference();
  TempDir dir;
  const std::string path = dir.file("scan.db");
  std::mt19937 rng(7);
  int kills = 0, finished_after = 0;
  uint32_t last_frame_seen = 0;
  // Added to a life after one that ended without a new checkpoint: a fresh process's first frames
  // cost several times the reference's mean (page faults), more so on a loaded machine, and with
  // lives of the mean's length alone all twenty kills could come before the first checkpoint.
  uint32_t extra_ms = 0;
  // A life lasts about a dozen frames on average, whatever this machine's speed.
  const auto span = static_cast<uint32_t>(std::max(1.0, 40.0 * ref.ms_per_frame));
  std::string progress;
  for (int life = 0; life < 200; ++life) {
    const pid_t child = fork();
    ASSERT_GE(child, 0);
    if (child == 0) scan_process(path);
    int status = 0;
    if (kills < 20) {
      std::this_thread::sleep_for(std::chrono::milliseconds(30 + extra_ms + rng() % span));
      kill(child, SIGKILL);
    }
    ASSERT_EQ(waitpid(child, &status, 0), child);
    if (WIFEXITED(status)) {
      ASSERT_EQ(WEXITSTATUS(status), 0) << "the scan process failed";
      finished_after = kills;
      break;
    }
    ++kills;
    // After each kill: intact, and the last checkpoint agrees with the uninterrupted run.
    auto s = ScanStore::open(path, OpenMode::kReadOnly);
    if (!s && s.status().code() == StatusCode::kNotFound) continue;  // killed before creating it
    ASSERT_TRUE(s) << s.status().to_string();
    auto integrity = (*s)->integrity_check();
    ASSERT_TRUE(integrity);
    ASSERT_TRUE(integrity->ok()) << integrity->problems.front();
    auto last = (*s)->last_checkpoint();
    ASSERT_TRUE(last);
    const uint32_t frame = *last ? (*last)->last_frame_id : 0;
    EXPECT_GE(frame, last_frame_seen);
    extra_ms = frame > last_frame_seen ? 0 : extra_ms + span / 2;
    last_frame_seen = frame;
    progress += " " + std::to_string(frame);
    s->reset();
    expect_same_poses(path, ref.poses, frame);
    if (HasFailure()) return;
  }
  EXPECT_GE(kills, 20);
  EXPECT_EQ(finished_after, kills);
  std::printf("%d kills (checkpointed frame after each:%s), then the scan finished\n", kills,
              progress.c_str());
  EXPECT_GT(last_frame_seen, 0u) << "no checkpoint before the last kill";
  EXPECT_LT(last_frame_seen, ref.frames.size()) << "the kills came after the scan";
  expect_same_cloud(stored_cloud(path), ref.cloud);
  expect_same_poses(path, ref.poses, ref.frames.size());
}

// A full disk in the middle of a scan (a file size limit in a child process): checkpoints and
// evictions fail and say so, fusion goes on, the last good checkpoint stays intact; once there is
// space again the next checkpoint writes everything, and the scan ends exactly as an
// uninterrupted run. Nothing is lost.
TEST(Recorder, FullDiskMidScanLosesNothing) {
  const Reference& ref = reference();
  TempDir dir;
  const std::string path = dir.file("scan.db");
  fflush(stdout);
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    signal(SIGXFSZ, SIG_IGN);
    auto made = ScanRecorder::create(path, metadata(), "[fusion]\n", "test", recorder_config(8.0));
    if (!made) _exit(3);
    ScanRecorder& recorder = **made;
    IncrementalReconstructor rec(config());
    const size_t full_at = 60, space_at = 240;
    uint64_t failed_checkpoints = 0;
    int64_t good_checkpoint = 0;
    for (size_t i = 0; i < ref.frames.size(); ++i) {
      if (i == full_at) {
        const auto size = std::filesystem::file_size(path);
        struct rlimit rl {static_cast<rlim_t>(size + 512 * 1024), RLIM_INFINITY};
        if (setrlimit(RLIMIT_FSIZE, &rl) != 0) _exit(4);
        good_checkpoint = recorder.status().last_checkpoint ? recorder.status().last_checkpoint->id : 0;
      }
      if (i == space_at) {
        struct rlimit rl {RLIM_INFINITY, RLIM_INFINITY};
        if (setrlimit(RLIMIT_FSIZE, &rl) != 0) _exit(5);
        // While the disk was full: the file still held the last good checkpoint, intact.
        auto r = ScanStore::open(path, OpenMode::kReadOnly);
        if (!r) _exit(6);
        auto last = (*r)->last_checkpoint();
        if (!last || !*last || (*last)->id != good_checkpoint) _exit(7);
        auto integrity = (*r)->integrity_check();
        if (!integrity || !integrity->ok()) _exit(8);
        if (failed_checkpoints == 0 || recorder.status().checkpoint_error.empty()) _exit(9);
        std::printf("disk full for frames %zu..%zu: %llu checkpoints failed (\"%s\"), pager failures %llu, "
                    "resident %.1f MiB\n",
                    full_at, space_at, static_cast<unsigned long long>(failed_checkpoints),
                    recorder.status().checkpoint_error.substr(0, 120).c_str(),
                    static_cast<unsigned long long>(recorder.status().pager.failures),
                    recorder.status().pager.resident_bytes / 1048576.0);
      }
      (void)recorder.prepare_frame(ref.frames[i], rec.initial_pose(ref.frames[i], std::nullopt), rec);
      auto rep = rec.process(ref.frames[i]);
      if (!rep) _exit(10);
      (void)recorder.record_frame(ref.frames[i], *rep, &rec.map());  // evictions may fail: kept
      if (i % 20 == 19 && !recorder.checkpoint(&rec.map(), "periodic")) {
        if (i < full_at || i >= space_at) _exit(11);
        if (recorder.status().last_error_code != StatusCode::kIoError) _exit(12);
        ++failed_checkpoints;
      }
    }
    rec.finish();
    if (!recorder.finish(&rec.map())) _exit(13);
    fflush(stdout);
    _exit(0);
  }
  int status = 0;
  ASSERT_EQ(waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status));
  ASSERT_EQ(WEXITSTATUS(status), 0);
  expect_same_cloud(stored_cloud(path), ref.cloud);
  expect_same_poses(path, ref.poses, ref.frames.size());
}

// Chunks removed from the map between checkpoints leave the file; a checkpoint of a map that never
// held a chunk (e.g. one taken before a resumed map was handed to the reconstructor) deletes
// nothing.
TEST(Recorder, RemovedChunksLeaveTheFileOthersNeverDo) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  RecorderConfig rc;
  rc.bounded_memory = true;
  {
    auto made = ScanRecorder::create(path, metadata(), "", "", rc);
    ASSERT_TRUE(made);
    PointMap map(0.5);
    for (int x = 0; x < 6; ++x) map.get_or_create({x, 0, 0}).points_for_write() = test::make_points({x, 0, 0}, 1, 20);
    ASSERT_TRUE((*made)->checkpoint(&map, "periodic"));
    ASSERT_TRUE(map.extract({2, 0, 0}, nullptr));
    map.get_or_create({4, 0, 0}).points_for_write().clear();  // emptied by the post-filter
    map.get_or_create({4, 0, 0}).dirty = true;
    auto rec = (*made)->checkpoint(&map, "periodic");
    ASSERT_TRUE(rec);
    EXPECT_EQ(rec->chunk_count, 4u);
  }
  ResumePoint at;
  auto resumed = ScanRecorder::resume(path, rc, &at);
  ASSERT_TRUE(resumed) << resumed.status().to_string();
  PointMap other(0.5);  // not the resumed map
  auto rec = (*resumed)->checkpoint(&other, "periodic");
  ASSERT_TRUE(rec);
  EXPECT_EQ(rec->chunk_count, 4u);
  EXPECT_EQ(rec->id, 3);
}

// A background checkpoint shares the changed chunks' points with the map instead of copying them:
// what fusion changes while the writer encodes must be copied first, so that the file holds the
// map as of the snapshot and the map keeps the change.
TEST(Recorder, BackgroundCheckpointHoldsTheMapAsOfItsSnapshot) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  RecorderConfig rc;
  rc.bounded_memory = true;
  auto made = ScanRecorder::create(path, metadata(), "", "", rc);
  ASSERT_TRUE(made) << made.status().to_string();
  ScanRecorder& rec = **made;
  PointMap map(0.5);
  ChunkContents at_snapshot;
  // Enough points that the writer is still encoding when the changes below are made.
  for (int x = 0; x < 200; ++x) {
    const ChunkKey k{x, 0, 0};
    map.get_or_create(k).points_for_write() = test::make_points(k, 1, 2000);
    at_snapshot[k] = map.find(k)->points();
  }
  ASSERT_TRUE(rec.checkpoint_in_background(&map, "periodic", {}));
  ChunkContents changed;
  map.for_each_chunk([&](const ChunkKey& k, Chunk& c) {
    PointArrays& a = c.points_for_write();
    for (Eigen::Vector3f& p : a.position_m) p.z() += 0.01f;
    a.state.front().merges += 1;
    a.push_back(a.get(0));
    c.dirty = true;
    changed[k] = c.points();
  });
  wait_for_background_checkpoint(rec);
  expect_same_cloud(stored_cloud(path), at_snapshot);
  expect_same_cloud(map_contents(map), changed);
}

// The same through fusion itself: frames fused while a background checkpoint is encoded change
// the chunks it shares (merges, visibility counts, new points), and the file still holds the map
// as of the checkpoint's frame.
TEST(Recorder, FusionWhileACheckpointIsEncodedLeavesItsSnapshotAlone) {
  const Reference& ref = reference();
  TempDir dir;
  const std::string path = dir.file("scan.db");
  RecorderConfig rc;
  rc.bounded_memory = true;
  auto made = ScanRecorder::create(path, metadata(), "[fusion]\n", "test", rc);
  ASSERT_TRUE(made) << made.status().to_string();
  ScanRecorder& recorder = **made;
  IncrementalReconstructor rec(config());
  const auto fuse = [&](size_t i) {
    ASSERT_TRUE(recorder.prepare_frame(ref.frames[i], rec.initial_pose(ref.frames[i], std::nullopt), rec));
    auto rep = rec.process(ref.frames[i]);
    ASSERT_TRUE(rep) << rep.status().to_string();
    ASSERT_TRUE(recorder.record_frame(ref.frames[i], *rep, &rec.map())) << recorder.status().last_error;
  };
  for (size_t i = 0; i < 40; ++i) fuse(i);
  const ChunkContents at_snapshot = map_contents(rec.map());
  ASSERT_TRUE(recorder.checkpoint_in_background(&rec.map(), "periodic", {}));
  for (size_t i = 40; i < 45; ++i) fuse(i);
  size_t changed = 0;
  for (const auto& [k, a] : map_contents(rec.map())) {
    const auto was = at_snapshot.find(k);
    changed += was != at_snapshot.end() && !(a == was->second);
  }
  EXPECT_GT(changed, 0u) << "the frames after the snapshot changed none of its chunks";
  wait_for_background_checkpoint(recorder);
  expect_same_cloud(stored_cloud(path), at_snapshot);
}
