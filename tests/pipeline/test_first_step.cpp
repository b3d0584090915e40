// A scan's first steps, before the motion model has a velocity: the track starts each from the
// last pose. The frames that arrive while a scan's first frame fuses (its map is empty, so it
// takes longest) can be dropped, and a handheld camera walking on moves and turns a long way in
// that gap. Tracking (the rig's per-frame path, track_sequence) must still take that step right.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <vector>

#include "depthfuse/batch.hpp"
#include "pipeline_test_util.hpp"

using namespace depthfuse;

namespace {

// The furnished room's walk from its first frame, with frames 1 to `gap` - 1 not given to the
// tracker, then `after` frames one by one. Returns the worst distance of a tracked camera from the
// truth, both relative to the first frame.
void check_first_step(size_t gap, size_t after, double max_worst_m) {
  auto seq = test::furnished_walk();
  ASSERT_TRUE(seq.is_ok()) << seq.status().to_string();
  std::vector<Frame> frames;
  std::vector<Pose> truth;
  for (size_t i = 0; i < gap + after; i = i == 0 ? gap : i + 1) {
    frames.push_back(seq->render(i));
    truth.push_back(seq->T_world_cam_true(i));
  }
  const Pose T_0_world = truth.front().inverse();
  const Eigen::Vector3d first_step_m =
      (T_0_world * truth[1]).translation() - (T_0_world * truth[0]).translation();
  auto r = track_sequence(frames, ReconstructionConfig{});
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  EXPECT_EQ(r->lost, 0u);
  double worst_m = 0;
  for (size_t i = 0; i < frames.size(); ++i)
    worst_m = std::max(worst_m, (r->T_world_cam[i].translation() -
                                 (T_0_world * truth[i]).translation()).norm());
  std::printf("first step over %zu frames (%.0f mm), then %zu frames: the track is %.1f mm from the "
              "truth at worst\n",
              gap, first_step_m.norm() * 1e3, after, worst_m * 1e3);
  EXPECT_GT(first_step_m.norm(), 0.05) << "the walk must move the camera in the gap";
  EXPECT_LT(worst_m, max_worst_m);
}

// Frames 1-7 dropped: the camera moves 72 mm and turns 7.5 degrees before the second frame, and
// the steady levels' gates, from the first pose, pair the wrong surfaces at the room's corner.
TEST(FirstStep, TheFramesBehindAScansFirstDroppedTheFirstStepIsStillTrackedRight) {
  check_first_step(8, 30, 0.02);
}

}  // namespace
