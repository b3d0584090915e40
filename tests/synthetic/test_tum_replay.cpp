// A written synthetic folder replays like recorded data through the TUM replay driver: same depth
// (within the PNG's 0.2 mm step), colour, intrinsics (camera.toml) and pose hints.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <iomanip>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

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

TEST(TumReplay, CameraFileReadsARollingShutterReadout) {
  testing::TempDir dir;
  const std::string path = (dir.path() / "camera.toml").string();
  auto write = [&](const std::string& readout) {
    std::FILE* f = std::fopen(path.c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fputs(("[camera]\nwidth = 640\nheight = 480\nfx = 517.3\nfy = 516.5\ncx = 318.6\n"
                "cy = 255.3\n" + readout).c_str(), f);
    std::fclose(f);
  };
  write("");
  auto cam = replay::read_camera_file(path);
  ASSERT_TRUE(cam.is_ok()) << cam.status().to_string();
  EXPECT_EQ(cam->intrinsics.row_readout_s, 0.0);  // a global shutter unless said otherwise
  write("row_readout_s = 0.03\n");
  cam = replay::read_camera_file(path);
  ASSERT_TRUE(cam.is_ok()) << cam.status().to_string();
  EXPECT_EQ(cam->intrinsics.row_readout_s, 0.03);
  write("row_readout_s = 0\n");
  EXPECT_TRUE(replay::read_camera_file(path).is_ok());
  write("row_readout_s = -0.03\n");
  cam = replay::read_camera_file(path);
  ASSERT_FALSE(cam.is_ok());
  EXPECT_NE(cam.status().message().find("camera.row_readout_s: must be in [0, 1] s"),
            std::string::npos)
      << cam.status().to_string();
}

// Two unsynchronised streams: here every colour image is stamped 20 ms before the depth frame it
// was taken with (30 Hz, so 13 ms after the previous one, which pairing by stamp alone then picks).
// The camera file's color_stamp_offset_s puts the colour stamps on the depth frames' clock.
TEST(TumReplay, ColourIsPairedWithTheDepthItWasTakenWithAfterTheCameraFilesOffset) {
  testing::TempDir dir;
  SyntheticConfig c;
  c.scene = SceneKind::kCorner;
  c.frames = 4;
  auto seq = SyntheticSequence::create(c);
  ASSERT_TRUE(seq.is_ok());
  const std::string folder = (dir.path() / "corner").string();
  ASSERT_TRUE(write_tum_folder(*seq, folder).is_ok());
  {
    std::ifstream in(folder + "/rgb.txt");
    std::ostringstream out;
    std::string line;
    while (std::getline(in, line)) {
      if (line.empty() || line[0] == '#') {
        out << line << "\n";
        continue;
      }
      std::istringstream fields(line);
      double t = 0;
      std::string path;
      fields >> t >> path;
      out << std::fixed << std::setprecision(6) << t - 0.020 << " " << path << "\n";
    }
    std::ofstream(folder + "/rgb.txt") << out.str();
  }
  std::vector<std::vector<uint8_t>> expected;
  for (size_t i = 0; i < 4; ++i) expected.push_back(seq->render(i).color.rgb);
  ASSERT_NE(expected[1], expected[2]);  // the camera moves: frames' colours differ

  auto colour_of = [&](std::optional<double> offset_s) {
    replay::TumReplayConfig rc;
    rc.color_stamp_offset_s = offset_s;
    auto src = replay::TumSource::open(folder, rc);
    EXPECT_TRUE(src.is_ok()) << src.status().to_string();
    std::vector<std::vector<uint8_t>> got;
    for (size_t i = 0; src.is_ok() && i < 4; ++i) {
      auto f = (*src)->next();
      EXPECT_TRUE(f.is_ok()) << f.status().to_string();
      got.push_back(f.is_ok() ? f->color.rgb : std::vector<uint8_t>{});
    }
    return got;
  };
  // By stamp alone depth frame 1 gets colour 2, taken a frame later.
  const auto by_stamp = colour_of(0.0);
  ASSERT_EQ(by_stamp.size(), 4u);
  EXPECT_EQ(by_stamp[1], expected[2]);

  const auto shifted = colour_of(0.020);
  ASSERT_EQ(shifted.size(), 4u);
  for (size_t i = 0; i < 4; ++i) EXPECT_EQ(shifted[i], expected[i]) << "frame " << i;

  // The folder's camera.toml says it when the caller does not.
  std::ostringstream camera;
  camera << std::ifstream(folder + "/camera.toml").rdbuf();
  std::ofstream(folder + "/camera.toml") << camera.str() << "color_stamp_offset_s = 0.02\n";
  const auto from_file = colour_of(std::nullopt);
  ASSERT_EQ(from_file.size(), 4u);
  for (size_t i = 0; i < 4; ++i) EXPECT_EQ(from_file[i], expected[i]) << "frame " << i;

  std::ofstream(folder + "/camera.toml") << camera.str() << "color_stamp_offset_s = 2\n";
  auto bad = replay::read_camera_file(folder + "/camera.toml");
  ASSERT_FALSE(bad.is_ok());
  EXPECT_NE(bad.status().message().find("camera.color_stamp_offset_s: must be in [-1, 1] s"),
            std::string::npos)
      << bad.status().to_string();
}

}  // namespace
}  // namespace depthfuse::synthetic
