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
