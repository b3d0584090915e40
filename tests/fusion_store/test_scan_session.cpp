// The fusion daemon's scan (ScanSession: the per-frame path over the SQLite checkpoint sink, as the
// daemon's worker drives it, without LCM) and `depthfuse reconstruct --track --iterations 0` run
// the same per-frame code: one sequence, with frames missing as a full queue drops them, tracked
// both ways, gives the same trajectory.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <sstream>

#include "core_test_util.hpp"
#include "depthfuse/replay/tum_source.hpp"
#include "depthfuse/trajectory.hpp"
#include "lcm_test_util.hpp"
#include "memory_budget.hpp"
#include "scan_session.hpp"
#include "sqlite_checkpoint_sink.hpp"

namespace depthfuse::testing {
namespace {

// Removes the lines of `path` whose number (from 0, after the comments) is in `drop`.
void drop_lines(const std::string& path, const std::vector<int>& drop) {
  std::ifstream in(path);
  std::stringstream kept;
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    if (!line.empty() && line[0] == '#') {
      kept << line << "\n";
      continue;
    }
    if (std::find(drop.begin(), drop.end(), n++) == drop.end()) kept << line << "\n";
  }
  in.close();
  std::ofstream(path) << kept.str();
}

TEST(ScanSession, TracksASequenceAsReconstructTrackDoes) {
  const std::string dir = temp_dir("scan-session");
  const std::string data = dir + "/rooms";
  std::string out;
  // The first 36 frames of a walk through the rooms at 30 Hz.
  ASSERT_EQ(run_command({bin("depthfuse"), "synth", "rooms", data, "--frames", "36"},
                        dir + "/synth.log", &out),
            0)
      << out;
  // Frames 12, 13 and 25 are missing, as a full queue drops frames: the motion model scales the
  // last step to the time since the last frame fused.
  drop_lines(data + "/depth.txt", {12, 13, 25});

  AppConfig config;
  config.fusion.scan_dir = dir + "/scans";
  fusiond::SqliteCheckpointSink sink(config, fusiond::SqliteSinkOptions{dir + "/scan.dfscan"});
  fusiond::ScanSession session(config, sink);
  auto started = session.start("session");
  ASSERT_TRUE(started.is_ok()) << started.status().to_string();
  auto source = replay::TumSource::open(data, replay::TumReplayConfig{});
  ASSERT_TRUE(source.is_ok()) << source.status().to_string();
  size_t frames = 0;
  for (;;) {
    auto f = (*source)->next();
    if (f.status().code() == StatusCode::kEndOfStream) break;
    ASSERT_TRUE(f.is_ok()) << f.status().to_string();
    ASSERT_FALSE(f->T_world_cam_hint) << "the frames must be tracked, not given poses";
    auto outcome = session.process(*f);
    ASSERT_TRUE(outcome.is_ok()) << outcome.status().to_string();
    EXPECT_TRUE(outcome->store_status.is_ok()) << outcome->store_status.to_string();
    ++frames;
  }
  EXPECT_EQ(frames, 33u);
  auto saved = session.stop("final", {});
  ASSERT_TRUE(saved.is_ok()) << saved.status().to_string();
  EXPECT_FALSE(session.active());

  ASSERT_EQ(run_command({bin("depthfuse"), "reconstruct", data, "--track", "--iterations", "0",
                         "-o", dir + "/batch.ply", "--trajectory-out", dir + "/batch.txt"},
                        dir + "/reconstruct.log", &out),
            0)
      << out;
  auto live = read_tum_trajectory(dir + "/scans/session-trajectory.txt");
  auto batch = read_tum_trajectory(dir + "/batch.txt");
  ASSERT_TRUE(live.is_ok()) << live.status().to_string();
  ASSERT_TRUE(batch.is_ok()) << batch.status().to_string();
  ASSERT_EQ(live->size(), batch->size());
  ASSERT_GT(live->size(), 30u) << "frames lost by tracking";
  for (size_t i = 0; i < live->size(); ++i) {
    const StampedPose& a = (*live)[i];
    const StampedPose& b = (*batch)[i];
    EXPECT_NEAR(a.timestamp_s, b.timestamp_s, 1e-6) << i;
    // The files keep 6 decimals of a position and 9 of a quaternion.
    EXPECT_LT((a.T_world_cam.translation() - b.T_world_cam.translation()).norm(), 2e-6) << i;
    EXPECT_TRUE(a.T_world_cam.linear().isApprox(b.T_world_cam.linear(), 1e-7)) << i;
  }
}

// After a loop closure the sweep moves points into chunks the pager has evicted; they wait for
// them in memory, and the scan file keeps chunks only, so a checkpoint joins them first: loading
// each chunk, moving it, sending some of its points on into others. On a long walk that was a few
// hundred milliseconds at once on the fusion thread, and the frame queue dropped frames. Once the
// sweep is done, the frames after it join a few each instead, and the checkpoint waits for them.
TEST(ScanSession, PointsMovedIntoEvictedChunksJoinThemFrameByFrame) {
  const std::string dir = temp_dir("scan-session-pending");
  AppConfig config;
  config.fusion.scan_dir = dir + "/scans";
  config.fusion.frame_log_interval_s = 0;
  // The map gets 4 MiB: a few metres of the wall below.
  config.fusion.memory_budget_mib = fusiond::MemoryBudget::of(config).frame_work_mib() + 4.0;
  fusiond::SqliteCheckpointSink sink(config, fusiond::SqliteSinkOptions{dir + "/scan.dfscan"});
  fusiond::ScanSession session(config, sink);
  ASSERT_TRUE(session.start("pending").is_ok());
  IncrementalReconstructor& rec = *session.reconstructor();
  const double wall_z = 2.2;
  uint32_t sequence = 0;
  const auto frame_at = [&](const Pose& T) {
    Frame f = test::render_plane(T, Eigen::Vector3d::UnitZ(), wall_z);
    f.T_world_cam_hint = T;
    f.sequence = ++sequence;
    f.utime = 1700000000000000LL + static_cast<int64_t>(sequence) * 1000000 / 30;
    return f;
  };
  // A camera walking 8 m along the wall, a keyframe every fourth frame; the start of the walk is
  // evicted as it goes.
  std::vector<Pose> keyframes;
  for (int i = 0; i <= 32; ++i) {
    const Pose T = Pose(Eigen::Translation3d(0.25 * i, 0, 0));
    if (i % 4 == 0) {
      keyframes.push_back(T);
      ASSERT_TRUE(rec.deformation().keyframe_added(i / 4, rec.next_frame_id(), T).is_ok());
    }
    auto out = session.process(frame_at(T));
    ASSERT_TRUE(out.is_ok()) << out.status().to_string();
    ASSERT_TRUE(out->report.fused());
  }
  // The closure: the whole walk 10 cm back along the wall, so that the resident chunks next to
  // the evicted ones send points into them.
  const Pose shift = Pose(Eigen::Translation3d(-0.1, 0, 0.02));
  std::vector<Pose> corrected;
  for (const Pose& T : keyframes) corrected.push_back(shift * T);
  ASSERT_TRUE(rec.deformation().correct(corrected).is_ok());
  const Pose end = shift * Pose(Eigen::Translation3d(8.0, 0, 0));
  int frames = 0;
  while (rec.deformation().sweeping()) {
    ASSERT_TRUE(session.process(frame_at(end)).is_ok());
    ASSERT_LT(++frames, 200) << "the sweep does not end";
  }
  ASSERT_TRUE(rec.deformation().has_pending_points())
      << "no point was moved into an evicted chunk: the test shows nothing";
  const std::vector<ChunkKey> waiting = rec.deformation().pending_keys();
  // Without a checkpoint, a few chunks a frame.
  frames = 0;
  while (rec.deformation().has_pending_points()) {
    ASSERT_TRUE(session.process(frame_at(end)).is_ok());
    ASSERT_LT(++frames, 100) << rec.deformation().pending_keys().size()
                             << " chunks still have points waiting";
  }
  EXPECT_GE(frames, 1);
  // Each in memory at the current version, or evicted again after it was joined.
  for (const ChunkKey& k : waiting) {
    if (const Chunk* c = rec.map().find(k)) {
      EXPECT_EQ(c->version, rec.deformation().version());
    }
  }
  auto saved = session.stop("final", {});
  ASSERT_TRUE(saved.is_ok()) << saved.status().to_string();
}

}  // namespace
}  // namespace depthfuse::testing
