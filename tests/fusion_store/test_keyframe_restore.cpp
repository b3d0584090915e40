// A resumed scan relocalises (issue 19): a scan of the synthetic corner is recorded into a real scan
// file through ScanRecorder and IncrementalReconstructor, as the fusion daemon does it, and
// "killed" halfway round its loop (both objects destroyed without a final checkpoint). A fresh
// reconstructor resumes from the file; the camera meanwhile went back to where the scan began,
// far from the last pose fused. With the relocaliser refilled from the file's keyframes its frames
// must be found and fused at the true pose; without (restoration not called, or no keyframes
// stored) they must stay lost. A keyframe whose depth fails its checksum is skipped, not fatal.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <chrono>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "depthfuse/pipeline.hpp"
#include "depthfuse/store/scan_recorder.hpp"
#include "depthfuse/synthetic/synthetic_sequence.hpp"
#include "store_test_util.hpp"

using namespace depthfuse;
using namespace depthfuse::store;

namespace {

constexpr int kLoopFrames = 300;  // a closed loop round the corner
constexpr int kStride = 3;        // every 3rd frame: on the corner 2.3 cm and 0.9 degree apart
constexpr int kCheckpointEvery = 10;  // recorded frames
constexpr int kReturnFrames = 10;

// Where the scan is killed, and where the camera is when it comes back (frame indices).
struct Walk {
  int kill_at = 150;   // the corner: half way round, the far side of the loop from its start
  int return_at = 15;  // 12 cm from frame 0
  // The scan before the kill is fused with the true poses as hints (ICP refines them), as from a
  // capture with a pose source: its map is then right wherever the tracker alone would drift.
  // The frames after the resume never have one.
  bool hints_before_kill = false;
};

Frame live_frame(const synthetic::SyntheticSequence& seq, size_t i) {
  Frame f = seq.render(i);
  f.T_world_cam_hint.reset();  // as from a Kinect: the reconstructor tracks
  return f;
}

RecorderConfig recorder_config(int keyframe_every_n_frames) {
  RecorderConfig rc;  // bounded memory, as in the daemon: a resume loads only near the last pose
  rc.keyframe_every_n_frames = keyframe_every_n_frames;
  return rc;
}

struct Recorded {
  uint32_t checkpoint_frame = 0;   // the last checkpoint's last frame
  size_t keyframes_covered = 0;    // keyframes of frames up to it
};

// Frames 0 .. kKillAt round the loop, a checkpoint every kCheckpointEvery frames, then a few more
// frames that no checkpoint covers (their keyframes must not count), then the "kill".
Recorded record(const synthetic::SyntheticSequence& seq, const std::string& path,
                int keyframe_every_n_frames, const Walk& walk = {}) {
  Recorded out;
  ScanMetadata meta;
  meta.scan_id = "restore";
  auto rec = ScanRecorder::create(path, meta, "", "", recorder_config(keyframe_every_n_frames));
  EXPECT_TRUE(rec.is_ok()) << rec.status().to_string();
  if (!rec) return out;
  IncrementalReconstructor recon{ReconstructionConfig{}};
  int recorded = 0;
  auto step = [&](size_t i) {
    Frame f = live_frame(seq, i);
    if (walk.hints_before_kill) f.T_world_cam_hint = seq.T_world_cam_true(0).inverse() * seq.T_world_cam_true(i);
    EXPECT_TRUE((*rec)->prepare_frame(f, recon.initial_pose(f, std::nullopt), recon).is_ok());
    auto r = recon.process(f);
    ASSERT_TRUE(r.is_ok()) << r.status().to_string();
    ASSERT_TRUE(r->fused()) << "frame " << i;
    EXPECT_TRUE((*rec)->record_frame(f, *r, &recon.map()).is_ok());
    ++recorded;
  };
  for (int i = 0; i <= walk.kill_at; i += kStride) {
    step(static_cast<size_t>(i));
    if (recorded % kCheckpointEvery == 0) {
      auto cp = (*rec)->checkpoint(&recon.map(), "periodic");
      EXPECT_TRUE(cp.is_ok()) << cp.status().to_string();
      if (cp) out.checkpoint_frame = cp->last_frame_id;
    }
  }
  // Not covered by a checkpoint: discarded by the resume, keyframes included.
  for (int k = 1; k <= 4; ++k) step(static_cast<size_t>(walk.kill_at + k * kStride));
  if (keyframe_every_n_frames > 0)
    out.keyframes_covered = (out.checkpoint_frame - 1) / keyframe_every_n_frames + 1;
  return out;
}

struct Resumed {
  std::optional<KeyframeRestoreReport> report;
  std::vector<FrameReport> back;
  std::vector<double> back_error_m;  // from the truth, in the first camera's frame
  size_t points_at_resume = 0, points_end = 0;
  size_t keyframes = 0;              // the relocaliser's after the restoration
  double restore_ms = 0;
};

// A fresh process's view of the file: resume, optionally restore the keyframes, then the frames
// of the camera where it went while the scan was down.
Resumed resume_and_return(const synthetic::SyntheticSequence& seq, const std::string& path,
                          bool restore, const Walk& walk = {}, bool load_views = true) {
  Resumed out;
  ResumePoint at;
  auto rec = ScanRecorder::resume(path, recorder_config(10), &at);
  EXPECT_TRUE(rec.is_ok()) << rec.status().to_string();
  if (!rec) return out;
  IncrementalReconstructor recon{ReconstructionConfig{}};
  recon.reset(std::move(at.map), at.next_frame_id, at.last_T_world_cam);
  if (restore) {
    const auto t0 = std::chrono::steady_clock::now();
    auto r = (*rec)->restore_keyframes(recon, load_views);
    out.restore_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    EXPECT_TRUE(r.is_ok()) << r.status().to_string();
    if (r) out.report = *r;
  }
  out.keyframes = recon.keyframe_count();
  out.points_at_resume = (*rec)->store().summary()->point_count;
  const Pose T_0_world = seq.T_world_cam_true(0).inverse();  // tracking started at the identity
  for (int k = 0; k < kReturnFrames; ++k) {
    const size_t i = static_cast<size_t>(walk.return_at + k * kStride);
    const Frame f = live_frame(seq, i);
    EXPECT_TRUE((*rec)->prepare_frame(f, recon.initial_pose(f, std::nullopt), recon).is_ok());
    auto r = recon.process(f);
    EXPECT_TRUE(r.is_ok()) << r.status().to_string();
    if (!r) return out;
    if (r->fused()) {
      EXPECT_TRUE((*rec)->record_frame(f, *r, &recon.map()).is_ok());
    }
    out.back.push_back(*r);
    const Pose truth = T_0_world * seq.T_world_cam_true(i);
    out.back_error_m.push_back((r->T_world_cam.translation() - truth.translation()).norm());
  }
  auto cp = (*rec)->checkpoint(&recon.map(), "command");
  EXPECT_TRUE(cp.is_ok()) << cp.status().to_string();
  if (cp) out.points_end = cp->point_count;
  return out;
}

void print(const Resumed& r) {
  if (r.report)
    std::printf("restored %zu keyframes from %zu stored (%zu chosen, %zu skipped, %zu chunks "
                "loaded) in %.1f ms\n",
                r.report->restored, r.report->stored, r.report->chosen, r.report->skipped.size(),
                r.report->chunks_loaded, r.restore_ms);
  for (size_t k = 0; k < r.back.size(); ++k)
    std::printf("back %zu: %s%s, fitness %.3f, %.1f mm from the truth\n", k,
                to_string(r.back[k].tracking), r.back[k].relocalised ? " (relocalised)" : "",
                r.back[k].registration.fitness, r.back_error_m[k] * 1e3);
  std::printf("points: %zu at the resume, %zu at the end\n", r.points_at_resume, r.points_end);
}

// The first frame back that was relocalised, or -1.
int first_relocalised(const Resumed& r) {
  for (size_t k = 0; k < r.back.size(); ++k)
    if (r.back[k].relocalised) return static_cast<int>(k);
  return -1;
}

void expect_found(const Resumed& r) {
  const int found = first_relocalised(r);
  ASSERT_GE(found, 0) << "not relocalised within " << kReturnFrames << " frames";
  for (int k = 0; k < found; ++k) EXPECT_FALSE(r.back[k].fused()) << "back " << k;
  for (size_t k = static_cast<size_t>(found); k < r.back.size(); ++k) {
    EXPECT_TRUE(r.back[k].fused()) << "back " << k;
    EXPECT_LT(r.back_error_m[k], 0.005) << "back " << k;
  }
  // Fused into the corner the map already holds, not as a second copy of it.
  EXPECT_GT(r.points_end, r.points_at_resume);
  EXPECT_LT(r.points_end, r.points_at_resume * 102 / 100);
}

// Without keyframes the camera is not found where it is: every frame is lost, or fused in the
// wrong place.
void expect_lost(const Resumed& r) {
  EXPECT_LT(first_relocalised(r), 0);
  ASSERT_EQ(r.back.size(), static_cast<size_t>(kReturnFrames));
  for (size_t k = 0; k < r.back.size(); ++k)
    EXPECT_TRUE(!r.back[k].fused() || r.back_error_m[k] > 0.05) << "back " << k;
}

// Flips one byte of a keyframe's depth blob inside its header (the element count): the header's
// CRC-32 no longer matches.
void damage_depth(const std::string& path, uint32_t frame_id) {
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  sqlite3_blob* blob = nullptr;
  ASSERT_EQ(sqlite3_blob_open(db, "main", "keyframes", "depth", frame_id, 1, &blob), SQLITE_OK)
      << sqlite3_errmsg(db);
  constexpr int kOffset = 9;
  unsigned char byte = 0;
  ASSERT_EQ(sqlite3_blob_read(blob, &byte, 1, kOffset), SQLITE_OK);
  byte ^= 0x5A;
  ASSERT_EQ(sqlite3_blob_write(blob, &byte, 1, kOffset), SQLITE_OK);
  sqlite3_blob_close(blob);
  sqlite3_close(db);
}

// Changes a keyframe row's capture time: the row's checksum no longer matches.
void damage_row(const std::string& path, uint32_t frame_id) {
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  const std::string sql =
      "UPDATE keyframes SET utime = utime + 1 WHERE frame_id = " + std::to_string(frame_id) + ";";
  ASSERT_EQ(sqlite3_exec(db, sql.c_str(), nullptr, nullptr, nullptr), SQLITE_OK) << sqlite3_errmsg(db);
  ASSERT_EQ(sqlite3_changes(db), 1);
  sqlite3_close(db);
}

class KeyframeRestore : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    synthetic::SyntheticConfig sc;
    sc.frames = kLoopFrames;
    auto s = synthetic::SyntheticSequence::create(sc);
    ASSERT_TRUE(s.is_ok()) << s.status().to_string();
    seq_ = new synthetic::SyntheticSequence(std::move(s).value());
  }
  static void TearDownTestSuite() {
    delete seq_;
    seq_ = nullptr;
  }
  static synthetic::SyntheticSequence* seq_;
  test::TempDir dir_{"kfrestore"};
};
synthetic::SyntheticSequence* KeyframeRestore::seq_ = nullptr;

TEST_F(KeyframeRestore, AResumedScanFindsACameraThatMovedWhileItWasDown) {
  const std::string path = dir_.file("scan.dfscan");
  const Recorded recorded = record(*seq_, path, 10);
  ASSERT_GT(recorded.checkpoint_frame, 0u);
  // The return place is far from the last pose fused: tracking from there cannot reach it.
  const Walk walk;
  const double apart_m = (seq_->T_world_cam_true(walk.kill_at).translation() -
                          seq_->T_world_cam_true(walk.return_at).translation()).norm();
  std::printf("the camera returns %.2f m from the last pose fused\n", apart_m);
  ASSERT_GT(apart_m, 1.0);

  // Each run resumes a copy: a resume writes the file.
  const std::string without = dir_.file("without.dfscan");
  std::filesystem::copy_file(path, without);
  {
    SCOPED_TRACE("restored");
    const Resumed r = resume_and_return(*seq_, path, /*restore=*/true);
    print(r);
    ASSERT_TRUE(r.report.has_value());
    // Only the checkpoint's keyframes count; all are intact.
    EXPECT_EQ(r.report->stored, recorded.keyframes_covered);
    EXPECT_TRUE(r.report->skipped.empty());
    EXPECT_GT(r.report->restored, 1u);
    EXPECT_LE(r.report->chosen, static_cast<size_t>(RelocalisationConfig{}.max_keyframes));
    // By place, newest first: keyframes are every 10 frames from frame 1, 23 cm apart, so every
    // other one is within the 0.3 m spacing of one kept; only those kept are decoded.
    EXPECT_EQ(r.report->restored_frames, (std::vector<uint32_t>{41, 21, 1}));
    EXPECT_EQ(r.report->chosen, 3u);
    EXPECT_EQ(r.keyframes, r.report->restored);
    expect_found(r);
  }
  {
    SCOPED_TRACE("not restored");
    const Resumed r = resume_and_return(*seq_, without, /*restore=*/false);
    print(r);
    EXPECT_EQ(r.keyframes, 0u);
    expect_lost(r);
  }
}

TEST_F(KeyframeRestore, WithoutStoredKeyframesTheCameraStaysLost) {
  const std::string path = dir_.file("scan.dfscan");
  const Recorded recorded = record(*seq_, path, /*keyframe_every_n_frames=*/0);
  ASSERT_GT(recorded.checkpoint_frame, 0u);
  const Resumed r = resume_and_return(*seq_, path, /*restore=*/true);
  print(r);
  ASSERT_TRUE(r.report.has_value());
  EXPECT_EQ(r.report->stored, 0u);
  EXPECT_EQ(r.report->restored, 0u);
  expect_lost(r);
}

TEST_F(KeyframeRestore, AKeyframeThatFailsItsChecksumIsSkipped) {
  const std::string path = dir_.file("scan.dfscan");
  const Recorded recorded = record(*seq_, path, 10);
  ASSERT_GT(recorded.checkpoint_frame, 0u);
  // Keyframes every 10 frames from frame 1, 23 cm apart on the loop: two apart are beyond the
  // 0.3 m spacing, neighbours within it.
  const uint32_t newest = (recorded.checkpoint_frame - 1) / 10 * 10 + 1;
  ASSERT_EQ(newest, 41u);
  // The newest keyframe the checkpoint covers, the first one tried: its depth fails.
  damage_depth(path, newest);
  // An older row (its time changed, so its checksum fails): left out of the listing.
  damage_row(path, 11);
  const Resumed r = resume_and_return(*seq_, path, /*restore=*/true);
  print(r);
  ASSERT_TRUE(r.report.has_value());
  ASSERT_EQ(r.report->skipped.size(), 2u);
  EXPECT_EQ(r.report->stored, recorded.keyframes_covered - 1);
  for (const std::string& why : r.report->skipped) std::printf("skipped: %s\n", why.c_str());
  // The listing comes first.
  EXPECT_NE(r.report->skipped[0].find("keyframe 11: checksum mismatch"), std::string::npos)
      << r.report->skipped[0];
  EXPECT_NE(r.report->skipped[1].find("keyframe 41 depth: blob header checksum mismatch"),
            std::string::npos) << r.report->skipped[1];
  // 41's neighbour takes its place (it would not have been wanted beside 41), then 1; 21 is within
  // the spacing of 31.
  EXPECT_EQ(r.report->restored_frames, (std::vector<uint32_t>{31, 1}));
  EXPECT_EQ(r.report->chosen, 3u);
  EXPECT_EQ(r.report->restored, r.keyframes);
  EXPECT_GT(r.report->restored, 1u);
  // The others still find the camera.
  expect_found(r);
}

// The rooms: the scan is killed two rooms on from where it began, far beyond the map a resume
// loads round the last pose (evict_distance_m). The camera is back at the start: a candidate pose
// there is verified against the map there, so the chunks the restored keyframes see must be
// loaded with them. Without them the keyframes alone do not find it.
TEST(KeyframeRestoreRooms, TheMapARestoredKeyframeSeesIsLoadedWithIt) {
  synthetic::SyntheticConfig sc;
  sc.scene = synthetic::SceneKind::kRooms;
  Walk walk;
  walk.kill_at = 450;  // 15 s at 0.5 m/s along the tour
  walk.return_at = 15;
  walk.hints_before_kill = true;  // the tracker alone slides along the rooms' walls
  sc.frames = walk.kill_at + 5 * kStride + 1;
  auto seq = synthetic::SyntheticSequence::create(sc);
  ASSERT_TRUE(seq.is_ok()) << seq.status().to_string();
  test::TempDir dir("kfrestore");
  const std::string path = dir.file("rooms.dfscan");
  const Recorded recorded = record(*seq, path, 10, walk);
  ASSERT_GT(recorded.checkpoint_frame, 0u);
  const double apart_m = (seq->T_world_cam_true(walk.kill_at).translation() -
                          seq->T_world_cam_true(walk.return_at).translation()).norm();
  std::printf("the camera returns %.2f m from the last pose fused\n", apart_m);
  ASSERT_GT(apart_m, 2 * RecorderConfig{}.pager.evict_distance_m);

  const std::string without = dir.file("without-views.dfscan");
  std::filesystem::copy_file(path, without);
  {
    SCOPED_TRACE("keyframes and their map");
    const Resumed r = resume_and_return(*seq, path, true, walk);
    print(r);
    ASSERT_TRUE(r.report.has_value());
    EXPECT_GT(r.report->chunks_loaded, 0u);
    expect_found(r);
  }
  {
    SCOPED_TRACE("keyframes without their map");
    const Resumed r = resume_and_return(*seq, without, true, walk, /*load_views=*/false);
    print(r);
    ASSERT_TRUE(r.report.has_value());
    EXPECT_EQ(r.report->chunks_loaded, 0u);
    EXPECT_EQ(r.keyframes, r.report->restored);
    expect_lost(r);
  }
}

}  // namespace
