// The fusion daemon's scan (ScanSession: the per-frame path over the SQLite checkpoint sink, as the
// daemon's worker drives it, without LCM) and `depthfuse reconstruct --track --iterations 0` run
// the same per-frame code: one sequence, with frames missing as a full queue drops them, tracked
// both ways, gives the same trajectory.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <sstream>

#include "depthfuse/replay/tum_source.hpp"
#include "depthfuse/trajectory.hpp"
#include "lcm_test_util.hpp"
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

}  // namespace
}  // namespace depthfuse::testing
