// A written synthetic folder replays like recorded data through the TUM replay driver: same depth
// (within the PNG's 0.2 mm step), colour, intrinsics (camera.toml) and pose hints.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>

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

// Issue 36: a TUM folder whose colour images are JPEG (as many RGB-D datasets ship them) stopped
// the replay at the first one. JPEG colour is read like PNG colour (within JPEG's loss).
TEST(TumReplay, JpegColourIsReadLikeThePng) {
  testing::TempDir dir;
  SyntheticConfig c;
  c.scene = SceneKind::kCorner;
  c.frames = 2;
  auto seq = SyntheticSequence::create(c);
  ASSERT_TRUE(seq.is_ok());
  const std::string folder = (dir.path() / "corner").string();
  ASSERT_TRUE(write_tum_folder(*seq, folder).is_ok());
  // Every colour PNG becomes a JPEG, and the list names the JPEGs.
  std::ifstream list_in(folder + "/rgb.txt");
  std::stringstream list;
  std::string line;
  while (std::getline(list_in, line)) {
    const size_t png = line.rfind(".png");
    if (line.empty() || line[0] == '#' || png == std::string::npos) {
      list << line << "\n";
      continue;
    }
    const std::string name = line.substr(line.find(' ') + 1);
    const std::string jpeg = name.substr(0, name.size() - 4) + ".jpg";
    const cv::Mat image = cv::imread(folder + "/" + name, cv::IMREAD_COLOR);
    ASSERT_FALSE(image.empty()) << name;
    ASSERT_TRUE(cv::imwrite(folder + "/" + jpeg, image, {cv::IMWRITE_JPEG_QUALITY, 95}));
    std::filesystem::remove(folder + "/" + name);
    list << line.substr(0, line.find(' ') + 1) << jpeg << "\n";
  }
  list_in.close();
  std::ofstream(folder + "/rgb.txt") << list.str();

  auto src = replay::TumSource::open(folder, {});
  ASSERT_TRUE(src.is_ok()) << src.status().to_string();
  for (size_t i = 0; i < 2; ++i) {
    auto f = (*src)->next();
    ASSERT_TRUE(f.is_ok()) << f.status().to_string();
    const Frame expected = seq->render(i);
    ASSERT_EQ(f->color.width, expected.color.width);
    ASSERT_EQ(f->color.rgb.size(), expected.color.rgb.size());
    double sum = 0;
    for (size_t k = 0; k < expected.color.rgb.size(); ++k)
      sum += std::abs(int{f->color.rgb[k]} - int{expected.color.rgb[k]});
    // Channels in the right order and places: JPEG at quality 95 is off by a level or two.
    EXPECT_LT(sum / expected.color.rgb.size(), 3.0);
  }
  // A JPEG that is not one is named; the depth frame is not taken without a word.
  const std::string first = folder + "/rgb/" +
                            std::filesystem::directory_iterator(folder + "/rgb")->path().filename().string();
  std::ofstream(first, std::ios::binary) << std::string("\xFF\xD8\xFF\xE0 broken", 11);
  auto broken = replay::TumSource::open(folder, {});
  ASSERT_TRUE(broken.is_ok()) << broken.status().to_string();
  Status st = Status::ok();
  for (size_t i = 0; i < 2 && st.is_ok(); ++i) st = (*broken)->load(i).status();
  EXPECT_EQ(st.code(), StatusCode::kCorrupt) << st.to_string();
  EXPECT_NE(st.message().find("cannot decode " + first), std::string::npos) << st.message();
}

// Issue 36: a FIFO given as an input file made the replay hang on opening it. Every file of a
// folder is refused unless it is a regular file, before it is opened for reading.
TEST(TumReplay, InputsThatAreNotRegularFilesAreRefused) {
  testing::TempDir dir;
  SyntheticConfig c;
  c.scene = SceneKind::kCorner;
  c.frames = 2;
  auto seq = SyntheticSequence::create(c);
  ASSERT_TRUE(seq.is_ok());
  const std::string clean = (dir.path() / "clean").string();
  ASSERT_TRUE(write_tum_folder(*seq, clean).is_ok());
  auto first_in = [](const std::string& folder, const std::string& sub) {
    std::vector<std::string> names;
    for (const auto& e : std::filesystem::directory_iterator(folder + "/" + sub))
      names.push_back(e.path().filename().string());
    std::sort(names.begin(), names.end());
    return sub + "/" + names.front();
  };
  for (const std::string& file : {std::string("depth.txt"), std::string("rgb.txt"),
                                  std::string("camera.toml"), std::string("groundtruth.txt"),
                                  first_in(clean, "depth"), first_in(clean, "rgb")}) {
    for (const bool fifo : {true, false}) {
      SCOPED_TRACE(file);
      const std::string folder = (dir.path() / "bad").string();
      std::filesystem::remove_all(folder);
      std::filesystem::copy(clean, folder, std::filesystem::copy_options::recursive);
      const std::string path = folder + "/" + file;
      std::filesystem::remove(path);
      if (fifo)
        ASSERT_EQ(::mkfifo(path.c_str(), 0600), 0);
      else
        std::filesystem::create_directory(path);
      replay::TumReplayConfig rc;
      rc.use_groundtruth = true;
      Status st = Status::ok();
      auto src = replay::TumSource::open(folder, rc);
      st = src.status();
      for (size_t i = 0; src && i < 2 && st.is_ok(); ++i) st = (*src)->load(i).status();
      EXPECT_NE(st.message().find(path + " is " + (fifo ? "a FIFO" : "a directory") +
                                  ", not a regular file"),
                std::string::npos)
          << st.to_string();
    }
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
