// Crash safety with real processes: a writer killed with SIGKILL at random moments, a full disk
// (a file size limit, and a real full tmpfs when the test may mount one).
#include <gtest/gtest.h>
#include <sched.h>
#include <signal.h>
#include <sys/mount.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <map>
#include <random>
#include <set>
#include <thread>

#include "depthfuse/store/scan_store.hpp"
#include "store_test_util.hpp"

using namespace depthfuse;
using namespace depthfuse::store;
using test::bit_equal;
using test::make_points;
using test::TempDir;

namespace {

// The writer is deterministic in the checkpoint number n, so the expected content of the file
// after any checkpoint can be recomputed. Checkpoint n:
//   S(n): 5 chunks staged before it begins (as the pager does), promoted by its commit;
//   W(n): 20 chunks written inside it;  D(n): one chunk deleted every third checkpoint;
//   poses of frames 10(n-1)+1 .. 10n inside it; a keyframe for frame 10n written before it.
constexpr int kKeys = 150;
ChunkKey key_of(int i) { return {i % 10, (i / 10) % 5 - 2, i / 50}; }
size_t count_for(int k, int n) { return 50 + static_cast<size_t>((k * 31 + n * 17) % 400); }
std::vector<int> staged_keys(int n) {
  std::vector<int> v;
  for (int j = 0; j < 5; ++j) v.push_back((n * 5 + j * 17) % kKeys);
  return v;
}
std::vector<int> written_keys(int n) {
  std::vector<int> v;
  for (int j = 0; j < 20; ++j) v.push_back((n * 7 + j * 13) % kKeys);
  return v;
}
std::optional<int> deleted_key(int n) {
  if (n % 3) return std::nullopt;
  return (n * 11) % kKeys;
}
Pose pose_of(uint32_t frame) {
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisd(frame * 0.01, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(frame * 0.01, 0, 1);
  return T;
}

// key index -> version (the checkpoint whose content it holds) after checkpoints 1..last.
std::map<int, int> expected_state(int last) {
  std::map<int, int> state;
  for (int n = 1; n <= last; ++n) {
    for (int k : staged_keys(n)) state[k] = n;
    for (int k : written_keys(n)) state[k] = n;
    if (auto d = deleted_key(n)) state.erase(*d);
  }
  return state;
}

Chunk chunk_for(int k, int n) {
  Chunk c;
  c.points_for_write() = make_points(key_of(k), static_cast<uint32_t>(n), count_for(k, n));
  c.last_touched_frame = static_cast<uint32_t>(n * 10);
  return c;
}

Keyframe keyframe_for(uint32_t frame) {
  Keyframe kf;
  kf.frame_id = frame;
  kf.utime = frame;
  kf.intrinsics = test::small_camera();
  kf.T_world_cam = pose_of(frame);
  kf.depth = DepthImage(kf.intrinsics.width, kf.intrinsics.height);
  for (size_t i = 0; i < kf.depth.depth_m.size(); ++i)
    kf.depth.depth_m[i] = static_cast<float>((i * 7 + frame) % 4000) / 1000.0f;
  return kf;
}

// One checkpoint of the deterministic writer.
Status write_checkpoint(ScanStore& s, int n) {
  std::vector<Chunk> staged;
  for (int k : staged_keys(n)) staged.push_back(chunk_for(k, n));
  std::vector<std::pair<ChunkKey, const Chunk*>> batch;
  for (size_t j = 0; j < staged.size(); ++j) batch.emplace_back(key_of(staged_keys(n)[j]), &staged[j]);
  DF_RETURN_IF_ERROR(s.stage_chunks({batch.begin(), batch.begin() + 2}));
  DF_RETURN_IF_ERROR(s.stage_chunks({batch.begin() + 2, batch.end()}));
  DF_RETURN_IF_ERROR(s.write_keyframe(keyframe_for(static_cast<uint32_t>(n * 10))));
  DF_RETURN_IF_ERROR(s.begin_checkpoint());
  auto body = [&]() -> Status {
    for (int k : written_keys(n)) DF_RETURN_IF_ERROR(s.write_chunk(key_of(k), chunk_for(k, n)));
    if (auto d = deleted_key(n)) DF_RETURN_IF_ERROR(s.delete_chunk(key_of(*d)));
    for (uint32_t f = static_cast<uint32_t>((n - 1) * 10 + 1); f <= static_cast<uint32_t>(n * 10); ++f) {
      PoseRecord p;
      p.frame_id = f;
      p.utime = f;
      p.T_world_cam = pose_of(f);
      DF_RETURN_IF_ERROR(s.write_pose(p));
    }
    return Status::ok();
  };
  Status st = body();
  if (!st) {
    s.rollback_checkpoint();
    return st;
  }
  CheckpointInfo info;
  info.last_frame_id = static_cast<uint32_t>(n * 10);
  info.T_world_cam = pose_of(info.last_frame_id);
  info.frames_fused = info.last_frame_id;
  auto rec = s.commit_checkpoint(info);
  if (!rec) return rec.status();
  if (rec->id != n) return internal_error("checkpoint numbered " + std::to_string(rec->id) + ", expected " + std::to_string(n));
  return Status::ok();
}

// Checks that the file holds exactly checkpoint `last` of the deterministic writer.
void expect_checkpoint_complete(ScanStore& s, int last) {
  ScopedRead snapshot(s);
  ASSERT_TRUE(snapshot.status());
  const std::map<int, int> want = expected_state(last);
  std::map<std::tuple<int, int, int>, int> index;
  for (int k = 0; k < kKeys; ++k) index[{key_of(k).x, key_of(k).y, key_of(k).z}] = k;
  size_t seen = 0;
  Status st = s.for_each_chunk([&](const ChunkInfo& info, PointArrays& a) {
    const int k = index.at({info.key.x, info.key.y, info.key.z});
    auto it = want.find(k);
    EXPECT_NE(it, want.end()) << "chunk " << to_string(info.key) << " should have been deleted";
    if (it != want.end()) {
      EXPECT_TRUE(bit_equal(a, make_points(info.key, it->second, count_for(k, it->second))))
          << "chunk " << to_string(info.key) << " is not version " << it->second;
    }
    ++seen;
    return Status::ok();
  });
  ASSERT_TRUE(st) << st.to_string();
  EXPECT_EQ(seen, want.size());
  auto poses = s.read_poses();
  ASSERT_TRUE(poses);
  ASSERT_EQ(poses->size(), static_cast<size_t>(last * 10));
  for (const PoseRecord& p : *poses) EXPECT_TRUE(p.T_world_cam.isApprox(pose_of(p.frame_id), 0.0));
  auto kfs = s.list_keyframes();
  ASSERT_TRUE(kfs);
  ASSERT_EQ(kfs->size(), static_cast<size_t>(last));
  for (size_t i = 0; i < kfs->size(); ++i) EXPECT_EQ((*kfs)[i].frame_id, (i + 1) * 10);
}

int last_checkpoint_id(ScanStore& s) {
  auto last = s.last_checkpoint();
  EXPECT_TRUE(last);
  return last && *last ? static_cast<int>((*last)->id) : 0;
}

}  // namespace

// A writer in a child process writes checkpoints continuously and is killed with SIGKILL after
// a random delay; each time the file must pass the integrity check, hold the last committed
// checkpoint completely (nothing of the interrupted one), and a new writer must carry on.
TEST(Crash, SigkillWhileWritingCheckpoints) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  { ASSERT_TRUE(ScanStore::open(path, OpenMode::kCreate)); }
  std::mt19937 rng(20240607);
  int rounds_with_progress = 0, killed_mid_checkpoint = 0, previous_last = 0;
  constexpr int kRounds = 24;
  for (int round = 0; round < kRounds; ++round) {
    int fds[2];
    ASSERT_EQ(pipe(fds), 0);
    const pid_t child = fork();
    ASSERT_GE(child, 0);
    if (child == 0) {
      close(fds[0]);
      auto s = ScanStore::open(path, OpenMode::kReadWrite);
      if (!s) _exit(3);
      int n = last_checkpoint_id(**s);
      for (;;) {
        ++n;
        const int32_t started = -n;
        (void)!write(fds[1], &started, sizeof(started));
        if (!write_checkpoint(**s, n)) _exit(4);
        (void)!write(fds[1], &n, sizeof(n));  // reported only after commit returned
      }
    }
    close(fds[1]);
    // A reader while the writer runs: its snapshot is one complete checkpoint.
    std::this_thread::sleep_for(std::chrono::milliseconds(rng() % 40));
    {
      auto r = ScanStore::open(path, OpenMode::kReadOnly);
      ASSERT_TRUE(r) << r.status().to_string();
      ScopedRead snapshot(**r);
      ASSERT_TRUE(snapshot.status());
      expect_checkpoint_complete(**r, last_checkpoint_id(**r));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(1 + rng() % 150));
    kill(child, SIGKILL);
    int status = 0;
    ASSERT_EQ(waitpid(child, &status, 0), child);
    ASSERT_TRUE(WIFSIGNALED(status)) << "writer exited with " << WEXITSTATUS(status);
    int committed = 0, last_started = 0;
    int32_t v;
    while (read(fds[0], &v, sizeof(v)) == sizeof(v)) {
      if (v > 0) committed = v;
      else last_started = -v;
    }
    close(fds[0]);
    if (last_started > committed) ++killed_mid_checkpoint;

    // As a reader finds it (before any writer recovers it) ...
    {
      auto r = ScanStore::open(path, OpenMode::kReadOnly);
      ASSERT_TRUE(r) << r.status().to_string();
      const int last = last_checkpoint_id(**r);
      EXPECT_GE(last, committed) << "a checkpoint reported committed is missing";
      EXPECT_GE(last, previous_last) << "checkpoints went backwards";
      // At most the one being written when the kill came (none if it came before the first).
      EXPECT_LE(last, std::max(last_started, previous_last));
      previous_last = last;
      expect_checkpoint_complete(**r, last);
      auto integrity = (*r)->integrity_check();
      ASSERT_TRUE(integrity);
      EXPECT_TRUE(integrity->ok()) << integrity->problems.front();
      if (last > 0) ++rounds_with_progress;
    }
    // ... and after a writer reopened it (the interrupted checkpoint's staging is discarded).
    {
      auto w = ScanStore::open(path, OpenMode::kReadWrite);
      ASSERT_TRUE(w) << w.status().to_string();
      expect_checkpoint_complete(**w, last_checkpoint_id(**w));
    }
    if (HasFailure()) break;
  }
  EXPECT_GT(rounds_with_progress, kRounds / 2);
  EXPECT_GT(killed_mid_checkpoint, 0) << "no kill landed inside a checkpoint";
  auto r = ScanStore::open(path, OpenMode::kReadOnly);
  ASSERT_TRUE(r);
  std::printf("after %d kills: %d checkpoints, %d kills inside a checkpoint\n", kRounds,
              last_checkpoint_id(**r), killed_mid_checkpoint);
}

namespace {

// In a child with a file size limit of `limit_bytes` (SIGXFSZ ignored, so writes fail with
// EFBIG): checkpoints fail cleanly, the process goes on, the file keeps the last good
// checkpoint, and once space is back checkpoints succeed again. Returns the child's exit code.
void full_disk_scenario(const std::string& path, int good, bool use_fsize_limit, rlim_t limit_bytes) {
  if (use_fsize_limit) {
    signal(SIGXFSZ, SIG_IGN);
    struct rlimit rl {limit_bytes, RLIM_INFINITY};
    ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &rl), 0);
  }
  auto w = ScanStore::open(path, OpenMode::kReadWrite);
  ASSERT_TRUE(w) << w.status().to_string();
  ScanStore& s = **w;
  // Keep writing until the disk is full.
  Status failed;
  int n = good;
  for (int i = 0; i < 200 && failed; ++i) {
    failed = write_checkpoint(s, n + 1);
    if (failed) ++n;
  }
  ASSERT_FALSE(failed) << "the disk never filled up";
  EXPECT_EQ(failed.code(), StatusCode::kIoError) << failed.to_string();
  const bool named = failed.message().find("disk full") != std::string::npos ||
                     failed.message().find("I/O error") != std::string::npos ||
                     failed.message().find("disk I/O") != std::string::npos;
  EXPECT_TRUE(named) << failed.to_string();
  std::printf("full disk reported as: %s\n", failed.to_string().c_str());
  EXPECT_FALSE(s.in_checkpoint());
  // The same connection still reads the last good checkpoint...
  EXPECT_EQ(last_checkpoint_id(s), n);
  expect_checkpoint_complete(s, n);
  // ... and so does a new reader, and the file is intact.
  {
    auto r = ScanStore::open(path, OpenMode::kReadOnly);
    ASSERT_TRUE(r) << r.status().to_string();
    EXPECT_EQ(last_checkpoint_id(**r), n);
    expect_checkpoint_complete(**r, n);
    auto integrity = (*r)->integrity_check();
    ASSERT_TRUE(integrity);
    EXPECT_TRUE(integrity->ok()) << integrity->problems.front();
  }
  // Failing again keeps failing cleanly (the writer retries on its next interval).
  Status again = write_checkpoint(s, n + 1);
  EXPECT_FALSE(again);
  if (use_fsize_limit) {
    // Space is back: the next checkpoint succeeds in the same process.
    struct rlimit rl {RLIM_INFINITY, RLIM_INFINITY};
    ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &rl), 0);
    Status ok = write_checkpoint(s, n + 1);
    ASSERT_TRUE(ok) << ok.to_string();
    expect_checkpoint_complete(s, n + 1);
  }
}

int run_in_child(const std::function<void()>& fn) {
  fflush(stdout);
  const pid_t child = fork();
  if (child == 0) {
    fn();
    fflush(stdout);
    _exit(::testing::Test::HasFailure() ? 1 : 0);
  }
  int status = 0;
  waitpid(child, &status, 0);
  if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
  return WEXITSTATUS(status);
}

void prepare_good_scan(const std::string& path, int checkpoints) {
  auto s = ScanStore::open(path, OpenMode::kCreate);
  ASSERT_TRUE(s);
  for (int n = 1; n <= checkpoints; ++n) ASSERT_TRUE(write_checkpoint(**s, n));
}

}  // namespace

TEST(Crash, FileSizeLimitFailsTheCheckpointAndKeepsTheLastGoodOne) {
  TempDir dir;
  const std::string path = dir.file("scan.db");
  prepare_good_scan(path, 3);
  const auto size = std::filesystem::file_size(path);
  const int code = run_in_child([&] { full_disk_scenario(path, 3, true, size + 256 * 1024); });
  ASSERT_EQ(code, 0);
  // After the child: the file is intact and holds what the child last committed.
  auto r = ScanStore::open(path, OpenMode::kReadOnly);
  ASSERT_TRUE(r) << r.status().to_string();
  const int last = last_checkpoint_id(**r);
  EXPECT_GT(last, 3);
  expect_checkpoint_complete(**r, last);
  auto integrity = (*r)->integrity_check();
  ASSERT_TRUE(integrity);
  EXPECT_TRUE(integrity->ok());
}

// A real full file system: a 3 MiB tmpfs in a private mount namespace (needs CAP_SYS_ADMIN;
// skipped otherwise). ENOSPC must surface as "disk full".
TEST(Crash, FullTmpfsFailsTheCheckpointAndKeepsTheLastGoodOne) {
  TempDir dir;
  const std::string mnt = dir.file("small-fs");
  std::filesystem::create_directory(mnt);
  const int code = run_in_child([&] {
    if (unshare(CLONE_NEWNS) != 0 || mount("none", "/", nullptr, MS_REC | MS_PRIVATE, nullptr) != 0 ||
        mount("tmpfs", mnt.c_str(), "tmpfs", 0, "size=3m") != 0) {
      _exit(77);
    }
    const std::string path = mnt + "/scan.db";
    prepare_good_scan(path, 2);
    if (::testing::Test::HasFailure()) return;
    full_disk_scenario(path, 2, false, 0);
    umount(mnt.c_str());
  });
  if (code == 77) GTEST_SKIP() << "cannot mount a tmpfs here (needs CAP_SYS_ADMIN)";
  EXPECT_EQ(code, 0);
}
