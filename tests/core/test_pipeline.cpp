// End to end on the analytic corner. (The noisy synthetic comparison of the three methods lives
// in tests/pipeline.)
#include <gtest/gtest.h>

#include "analytic.hpp"
#include "depthfuse/pipeline.hpp"

using namespace depthfuse;

TEST(Batch, RejectsEmptyAndMismatchedInput) {
  auto r = reconstruct_batch({}, {}, ReconstructionConfig{});
  EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);
  std::vector<Frame> frames(1, test::render_corner(test::look_at({2, 2, 1.5}, {0.3, 0.3, 0.3})));
  auto r2 = reconstruct_batch(frames, {}, ReconstructionConfig{});
  EXPECT_EQ(r2.status().code(), StatusCode::kInvalidArgument);
}

TEST(Incremental, TracksTheCornerWithoutPoses) {
  ReconstructionConfig c;
  IncrementalReconstructor rec(c);
  // A slow sweep: 12 frames, 1.5 cm and 0.5 degree apart.
  std::vector<Pose> truth;
  for (int i = 0; i < 12; ++i) {
    const double a = 0.6 + i * 0.01;
    truth.push_back(test::look_at({2.4 * std::cos(a), 2.4 * std::sin(a), 1.4}, {0.3, 0.3, 0.3}));
  }
  std::optional<Pose> prediction = truth[0];
  for (size_t i = 0; i < truth.size(); ++i) {
    Frame f = test::render_corner(truth[i]);
    auto r = rec.process(f, i == 0 ? prediction : std::nullopt);
    ASSERT_TRUE(r.is_ok()) << r.status().to_string();
    EXPECT_LT((r->T_world_cam.translation() - truth[i].translation()).norm(), 3e-3) << "frame " << i;
  }
  EXPECT_GT(rec.map().point_count(), 100000u);
}

TEST(Incremental, ReusesTheModelOnlyForNearbyFramesAndNotTwiceInARow) {
  // Frames 1.2 cm apart with pose hints 5 mm off: every other frame aligns to the model rendered
  // for the frame before (registration.live_model_reuse_frames = 2); after a 6 cm jump the map
  // is rendered again. The refined poses are as good either way.
  ReconstructionConfig c;
  ASSERT_EQ(c.registration.live_model_reuse_frames, 2);
  IncrementalReconstructor rec(c);
  std::vector<Pose> truth;
  for (int i = 0; i < 7; ++i) {
    const double a = 0.6 + i * 0.005;
    truth.push_back(test::look_at({2.4 * std::cos(a), 2.4 * std::sin(a), 1.4}, {0.3, 0.3, 0.3}));
  }
  truth.push_back(test::look_at({2.4 * std::cos(0.66), 2.4 * std::sin(0.66), 1.42}, {0.3, 0.3, 0.3}));
  std::vector<bool> reused;
  for (size_t i = 0; i < truth.size(); ++i) {
    Frame f = test::render_corner(truth[i]);
    Pose hint = truth[i];
    if (i > 0) hint.translation() += Eigen::Vector3d(0.003, -0.003, 0.002);
    f.T_world_cam_hint = hint;
    auto r = rec.process(f);
    ASSERT_TRUE(r.is_ok()) << r.status().to_string();
    if (i > 0) {
      ASSERT_TRUE(r->registered) << "frame " << i;
      EXPECT_LT((r->T_world_cam.translation() - truth[i].translation()).norm(), 1e-3) << "frame " << i;
    }
    reused.push_back(r->model_reused);
  }
  // Frame 0 has no map to register to; 1 renders; 2 reuses; 3 renders; ... ; 7 jumped: renders.
  EXPECT_EQ(reused, (std::vector<bool>{false, false, true, false, true, false, true, false}));

  ReconstructionConfig never = c;
  never.registration.live_model_reuse_frames = 1;
  IncrementalReconstructor rec1(never);
  for (size_t i = 0; i < 3; ++i) {
    Frame f = test::render_corner(truth[i]);
    f.T_world_cam_hint = truth[i];
    auto r = rec1.process(f);
    ASSERT_TRUE(r.is_ok());
    EXPECT_FALSE(r->model_reused);
  }
}
