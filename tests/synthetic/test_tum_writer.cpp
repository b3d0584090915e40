// The TUM folder writer: every file read back (PNG through OpenCV, text by hand, TOML through the
// scene reader) and compared with what the sequence renders.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "depthfuse/synthetic/tum_writer.hpp"
#include "synthetic_test_util.hpp"

namespace depthfuse::synthetic {
namespace {

namespace fs = std::filesystem;
using testing::TempDir;

std::string read_file(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// Non-comment lines split into whitespace-separated fields.
std::vector<std::vector<std::string>> read_table(const fs::path& p) {
  std::vector<std::vector<std::string>> rows;
  std::ifstream in(p);
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ls(line);
    std::vector<std::string> fields;
    std::string f;
    while (ls >> f) fields.push_back(f);
    rows.push_back(fields);
  }
  return rows;
}

Pose pose_from_row(const std::vector<std::string>& r) {
  Pose T = Pose::Identity();
  T.translation() = Eigen::Vector3d(std::stod(r[1]), std::stod(r[2]), std::stod(r[3]));
  T.linear() =
      Eigen::Quaterniond(std::stod(r[7]), std::stod(r[4]), std::stod(r[5]), std::stod(r[6]))
          .normalized()
          .toRotationMatrix();
  return T;
}

SyntheticSequence make(SyntheticConfig c) {
  auto s = SyntheticSequence::create(c);
  EXPECT_TRUE(s.is_ok()) << s.status().to_string();
  return std::move(s).value();
}

TEST(TumWriter, TimestampFormat) {
  EXPECT_EQ(tum_timestamp(0), "0.000000");
  EXPECT_EQ(tum_timestamp(33333), "0.033333");
  EXPECT_EQ(tum_timestamp(1305031102175304), "1305031102.175304");
}

TEST(TumWriter, FolderReadsBackAsWritten) {
  TempDir dir;
  SyntheticConfig c;
  c.scene = SceneKind::kRoom;
  c.frames = 3;
  c.seed = 9;
  c.pose_noise_m = 0.01;
  c.pose_noise_deg = 0.5;
  const SyntheticSequence seq = make(c);
  const fs::path root = dir.path() / "scan";  // created by the writer
  const Status st = write_tum_folder(seq, root.string());
  ASSERT_TRUE(st.is_ok()) << st.to_string();

  for (const char* f : {"depth.txt", "rgb.txt", "groundtruth.txt", "poses_perturbed.txt",
                        "camera.toml", "scene.toml", "README.txt"})
    EXPECT_TRUE(fs::is_regular_file(root / f)) << f;

  const auto depth_rows = read_table(root / "depth.txt");
  const auto rgb_rows = read_table(root / "rgb.txt");
  const auto truth_rows = read_table(root / "groundtruth.txt");
  const auto perturbed_rows = read_table(root / "poses_perturbed.txt");
  ASSERT_EQ(depth_rows.size(), 3u);
  ASSERT_EQ(rgb_rows.size(), 3u);
  ASSERT_EQ(truth_rows.size(), 3u);
  ASSERT_EQ(perturbed_rows.size(), 3u);
  EXPECT_EQ(depth_rows[1][0], "0.033333");
  EXPECT_EQ(depth_rows[1][1], "depth/0.033333.png");
  EXPECT_EQ(rgb_rows[2][1], "rgb/0.066667.png");

  for (size_t i = 0; i < 3; ++i) {
    const Frame f = seq.render(i);
    const cv::Mat depth = cv::imread((root / depth_rows[i][1]).string(), cv::IMREAD_UNCHANGED);
    ASSERT_EQ(depth.type(), CV_16UC1);
    ASSERT_EQ(depth.cols, 512);
    ASSERT_EQ(depth.rows, 424);
    double worst = 0;
    size_t valid = 0;
    for (int v = 0; v < depth.rows; ++v)
      for (int u = 0; u < depth.cols; ++u) {
        const double z = f.depth.at(u, v);
        const uint16_t raw = depth.at<uint16_t>(v, u);
        if (z <= 0) {
          ASSERT_EQ(raw, 0) << u << "," << v;
          continue;
        }
        ++valid;
        worst = std::max(worst, std::fabs(raw / 5000.0 - z));
      }
    EXPECT_LE(worst, 0.0001 + 1e-9);  // half of the 0.2 mm step
    EXPECT_GT(valid, 100000u);

    const cv::Mat bgr = cv::imread((root / rgb_rows[i][1]).string(), cv::IMREAD_COLOR);
    ASSERT_EQ(bgr.type(), CV_8UC3);
    size_t colour_mismatch = 0;
    for (int v = 0; v < bgr.rows; ++v)
      for (int u = 0; u < bgr.cols; ++u) {
        const cv::Vec3b p = bgr.at<cv::Vec3b>(v, u);
        const uint8_t* rgb = &f.color.rgb[3 * (static_cast<size_t>(v) * 512 + u)];
        colour_mismatch += p[0] != rgb[2] || p[1] != rgb[1] || p[2] != rgb[0];
      }
    EXPECT_EQ(colour_mismatch, 0u);

    EXPECT_TRUE(pose_from_row(truth_rows[i]).isApprox(seq.T_world_cam_true(i), 1e-8));
    EXPECT_TRUE(pose_from_row(perturbed_rows[i]).isApprox(seq.T_world_cam_perturbed(i), 1e-8));
    EXPECT_FALSE(pose_from_row(perturbed_rows[i]).isApprox(seq.T_world_cam_true(i), 1e-4));
  }

  EXPECT_EQ(
      read_file(root / "camera.toml").substr(read_file(root / "camera.toml").find("[camera]")),
      "[camera]\nwidth = 512\nheight = 424\nfx = 365.0\nfy = 365.0\ncx = 255.5\ncy = 211.5\n"
      "depth_scale = 5000.0\n");

  // scene.toml: the analytic ground truth and the settings that reproduce the folder.
  auto scene = Scene::load_toml((root / "scene.toml").string());
  ASSERT_TRUE(scene.is_ok()) << scene.status().to_string();
  EXPECT_EQ(scene->to_toml(), seq.scene().to_toml());
  auto gen = parse_synthetic_config_toml(read_file(root / "scene.toml"));
  ASSERT_TRUE(gen.is_ok()) << gen.status().to_string();
  EXPECT_EQ(gen->seed, 9u);
  EXPECT_EQ(gen->frames, 3);
  EXPECT_EQ(gen->pose_noise_deg, 0.5);
  auto again = SyntheticSequence::create(*gen);
  ASSERT_TRUE(again.is_ok());
  EXPECT_EQ(again->render(1).depth.depth_m, seq.render(1).depth.depth_m);
}

TEST(TumWriter, WithoutColourAndWithoutPoseNoise) {
  TempDir dir;
  SyntheticConfig c;
  c.frames = 2;
  const SyntheticSequence seq = make(c);
  ASSERT_TRUE(write_tum_folder(seq, dir.path().string(), false).is_ok());
  EXPECT_FALSE(fs::exists(dir.path() / "rgb"));
  EXPECT_FALSE(fs::exists(dir.path() / "rgb.txt"));
  const auto truth = read_table(dir.path() / "groundtruth.txt");
  const auto perturbed = read_table(dir.path() / "poses_perturbed.txt");
  EXPECT_EQ(truth, perturbed);
}

TEST(TumWriter, ErrorsNameThePath) {
  TempDir dir;
  const fs::path file = dir.path() / "not_a_folder";
  std::ofstream(file) << "x";
  SyntheticConfig c;
  c.frames = 1;
  const SyntheticSequence seq = make(c);
  const Status st = write_tum_folder(seq, (file / "scan").string());
  ASSERT_FALSE(st.is_ok());
  EXPECT_EQ(st.code(), StatusCode::kIoError);
  EXPECT_NE(st.message().find((file / "scan").string()), std::string::npos) << st.message();

  // A depth folder that cannot be written into.
  const fs::path root = dir.path() / "blocked";
  fs::create_directories(root);
  std::ofstream(root / "depth") << "a file where the depth folder should be";
  const Status st2 = write_tum_folder(seq, root.string());
  ASSERT_FALSE(st2.is_ok());
  EXPECT_NE(st2.message().find("depth"), std::string::npos) << st2.message();
}

}  // namespace
}  // namespace depthfuse::synthetic
