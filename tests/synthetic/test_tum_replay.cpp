// A written synthetic folder replays like recorded data through the TUM replay driver: same depth
// (within the PNG's 0.2 mm step), colour, intrinsics (camera.toml) and pose hints.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "depthfuse/replay/tum_source.hpp"
#include "depthfuse/synthetic/tum_writer.hpp"
#include "synthetic_test_util.hpp"

namespace depthfuse::synthetic {
namespace {

TEST(TumReplay, WrittenFolderReplaysAsRecordedData) {
  testing::TempDir dir;
  SyntheticConfig c;
  c.scene = SceneKind::kCorner;
  c.frames = 3;
  c.pose_noise_m = 0.01;
  c.pose_noise_deg = 0.3;
  auto seq = SyntheticSequence::create(c);
  ASSERT_TRUE(seq.is_ok());
  const std::string folder = (dir.path() / "corner").string();
  ASSERT_TRUE(write_tum_folder(*seq, folder).is_ok());

  replay::TumReplayConfig rc;
  rc.poses_path = folder + "/poses_perturbed.txt";
  auto src = replay::TumSource::open(folder, rc);
  ASSERT_TRUE(src.is_ok()) << src.status().to_string();
  EXPECT_EQ((*src)->intrinsics_origin(), "camera.toml");
  EXPECT_EQ((*src)->intrinsics().fx, 365.0);
  EXPECT_EQ((*src)->intrinsics().cx, 255.5);
  EXPECT_EQ((*src)->depth_scale(), 5000.0);
  ASSERT_EQ((*src)->frame_count(), 3u);
  for (size_t i = 0; i < 3; ++i) {
    auto f = (*src)->next();
    ASSERT_TRUE(f.is_ok()) << f.status().to_string();
    const Frame expected = seq->render(i);
    ASSERT_EQ(f->depth.depth_m.size(), expected.depth.depth_m.size());
    double worst = 0;
    for (size_t k = 0; k < expected.depth.depth_m.size(); ++k)
      worst = std::max(worst, std::fabs(double{f->depth.depth_m[k]} - expected.depth.depth_m[k]));
    EXPECT_LE(worst, 1e-4 + 1e-6);  // half the 0.2 mm step, plus float rounding in the reader
    EXPECT_EQ(f->color.rgb, expected.color.rgb);
    ASSERT_TRUE(f->T_world_cam_hint.has_value());
    EXPECT_TRUE(f->T_world_cam_hint->isApprox(seq->T_world_cam_perturbed(i), 1e-7));
  }
}

}  // namespace
}  // namespace depthfuse::synthetic
