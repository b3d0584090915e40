// File formats and bad input: PLY, TUM trajectories, TUM folders.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include <opencv2/imgcodecs.hpp>

#include "depthfuse/ply.hpp"
#include "depthfuse/replay/tum_source.hpp"
#include "depthfuse/trajectory.hpp"

using namespace depthfuse;
namespace fs = std::filesystem;

namespace {

struct TempDir {
  fs::path path;
  TempDir() {
    path = fs::temp_directory_path() / ("df_test_" + std::to_string(::getpid()) + "_" +
                                        std::to_string(counter()++));
    fs::create_directories(path);
  }
  ~TempDir() { fs::remove_all(path); }
  static int& counter() { static int c = 0; return c; }
  std::string operator/(const std::string& f) const { return (path / f).string(); }
};

void write_text(const std::string& path, const std::string& text) { std::ofstream(path) << text; }

// A two-frame TUM folder of 64x48 depth PNGs.
void make_folder(const TempDir& d, int w = 64, int h = 48) {
  fs::create_directories(d / "depth");
  cv::Mat img(h, w, CV_16UC1, cv::Scalar(10000));  // 2 m at scale 5000
  cv::imwrite(d / "depth/1.000000.png", img);
  cv::imwrite(d / "depth/1.033333.png", img);
  write_text(d / "depth.txt", "# depth\n1.000000 depth/1.000000.png\n1.033333 depth/1.033333.png\n");
  write_text(d / "camera.toml", "[camera]\nwidth = 64\nheight = 48\nfx = 50.0\nfy = 50.0\ncx = 31.5\ncy = 23.5\n");
}

}  // namespace

TEST(Ply, RoundTrip) {
  TempDir d;
  PointArrays a;
  for (int i = 0; i < 1000; ++i) {
    PointRecord r;
    r.position_m = {i * 0.01f, -i * 0.02f, 1.0f + i};
    r.normal = Eigen::Vector3f(1, i, 2).normalized();
    r.rgb[0] = i % 256; r.rgb[1] = 7; r.rgb[2] = 200;
    r.merges = i;
    r.violations = i / 3;
    r.information[0] = r.information[3] = r.information[5] = 1e6f;
    a.push_back(r);
  }
  ASSERT_TRUE(write_ply(d / "c.ply", a).is_ok());
  auto b = read_ply(d / "c.ply");
  ASSERT_TRUE(b.is_ok()) << b.status().to_string();
  ASSERT_EQ(b->size(), a.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(b->position_m[i].x(), a.position_m[i].x());
    EXPECT_EQ(b->state[i].nz, a.state[i].nz);
    EXPECT_EQ(b->state[i].r, a.state[i].r);
    EXPECT_EQ(b->state[i].merges, a.state[i].merges);
  }
}

TEST(Ply, TruncatedFileIsReported) {
  TempDir d;
  PointArrays a;
  for (int i = 0; i < 100; ++i) a.push_back(PointRecord{});
  ASSERT_TRUE(write_ply(d / "c.ply", a).is_ok());
  fs::resize_file(d / "c.ply", fs::file_size(d / "c.ply") - 10);
  auto b = read_ply(d / "c.ply");
  ASSERT_FALSE(b.is_ok());
  EXPECT_NE(b.status().message().find("truncated"), std::string::npos);
}

// A header's vertex count is checked against the file before anything is allocated for it.
TEST(Ply, ImpossibleVertexCountIsReportedBeforeAllocating) {
  TempDir d;
  const std::string header =
      "ply\nformat binary_little_endian 1.0\nelement vertex COUNT\nproperty float x\n"
      "property float y\nproperty float z\nend_header\n";
  for (const std::string count : {"4000000000", "-1", "18446744073709551616", "12abc"}) {
    std::string text = header;
    text.replace(text.find("COUNT"), 5, count);
    write_text(d / "c.ply", text + std::string(12 * 3, '\0'));
    auto b = read_ply(d / "c.ply");
    ASSERT_FALSE(b.is_ok()) << count;
    EXPECT_EQ(b.status().code(), StatusCode::kCorrupt) << count << ": " << b.status().to_string();
  }
  std::string three = header;
  three.replace(three.find("COUNT"), 5, "3");
  write_text(d / "c.ply", three + std::string(12 * 3, '\0'));
  auto b = read_ply(d / "c.ply");
  ASSERT_TRUE(b.is_ok()) << b.status().to_string();
  EXPECT_EQ(b->size(), 3u);
}

TEST(Trajectory, RoundTripAndNearest) {
  TempDir d;
  std::vector<StampedPose> poses(3);
  for (int i = 0; i < 3; ++i) {
    poses[i].timestamp_s = 10 + i * 0.1;
    poses[i].T_world_cam.translation() = Eigen::Vector3d(i, 2 * i, -i);
    poses[i].T_world_cam.linear() = Eigen::AngleAxisd(0.1 * i, Eigen::Vector3d::UnitY()).toRotationMatrix();
  }
  ASSERT_TRUE(write_tum_trajectory(d / "t.txt", poses).is_ok());
  auto back = read_tum_trajectory(d / "t.txt");
  ASSERT_TRUE(back.is_ok());
  ASSERT_EQ(back->size(), 3u);
  EXPECT_TRUE((*back)[2].T_world_cam.isApprox(poses[2].T_world_cam, 1e-6));
  EXPECT_EQ(nearest_pose(*back, 10.11, 0.02), 1);
  EXPECT_EQ(nearest_pose(*back, 10.5, 0.02), -1);
}

TEST(Trajectory, BadInputNamesFileAndLine) {
  TempDir d;
  const std::pair<std::string, std::string> cases[] = {
      {"1 0 0 0 0 0 0 1\n2 nan 0 0 0 0 0 1\n", ":2: field 2 is nan"},
      {"1 0 0 0 0 0 0 1\n2 0 0 zero 0 0 0 1\n", ":2: field 4 'zero' is not a number"},
      {"1 0 0 0 0 0 1\n", ":1: expected 8 fields"},
      {"1 0 0 0 0 0 0 2\n", ":1: quaternion is not unit"},
      {"# nothing\n", "no poses"},
  };
  for (const auto& [text, expected] : cases) {
    write_text(d / "t.txt", text);
    auto r = read_tum_trajectory(d / "t.txt");
    ASSERT_FALSE(r.is_ok()) << text;
    EXPECT_NE(r.status().message().find(expected), std::string::npos) << r.status().message();
  }
}

TEST(TumFolder, ReadsDepthWithCameraFile) {
  TempDir d;
  make_folder(d);
  auto src = replay::TumSource::open(d.path.string(), replay::TumReplayConfig{});
  ASSERT_TRUE(src.is_ok()) << src.status().to_string();
  EXPECT_EQ((*src)->intrinsics().width, 64);
  auto f = (*src)->next();
  ASSERT_TRUE(f.is_ok()) << f.status().to_string();
  EXPECT_FLOAT_EQ(f->depth.at(5, 5), 2.0f);
  ASSERT_TRUE((*src)->next().is_ok());
  EXPECT_EQ((*src)->next().status().code(), StatusCode::kEndOfStream);
}

TEST(TumFolder, BadInputGetsClearErrors) {
  {
    TempDir d;
    make_folder(d);
    fs::remove(d / "depth/1.033333.png");
    auto src = replay::TumSource::open(d.path.string(), replay::TumReplayConfig{});
    ASSERT_TRUE(src.is_ok());
    ASSERT_TRUE((*src)->next().is_ok());
    auto f = (*src)->next();
    EXPECT_EQ(f.status().code(), StatusCode::kNotFound);
    EXPECT_NE(f.status().message().find("1.033333.png"), std::string::npos);
  }
  {
    TempDir d;
    make_folder(d);
    write_text(d / "depth/1.000000.png", "\x89PNG\r\n\x1a\n garbage that is not a png");
    auto src = replay::TumSource::open(d.path.string(), replay::TumReplayConfig{});
    ASSERT_TRUE(src.is_ok());
    auto f = (*src)->next();
    EXPECT_EQ(f.status().code(), StatusCode::kCorrupt) << f.status().to_string();
  }
  {
    TempDir d;
    make_folder(d);
    cv::imwrite(d / "depth/1.000000.png", cv::Mat(40, 30, CV_16UC1, cv::Scalar(1)));
    auto src = replay::TumSource::open(d.path.string(), replay::TumReplayConfig{});
    ASSERT_TRUE(src.is_ok());
    auto f = (*src)->next();
    EXPECT_EQ(f.status().code(), StatusCode::kInvalidArgument);
    EXPECT_NE(f.status().message().find("30x40"), std::string::npos) << f.status().message();
  }
  {
    TempDir d;
    make_folder(d);
    write_text(d / "depth.txt", "# no frames\n");
    auto src = replay::TumSource::open(d.path.string(), replay::TumReplayConfig{});
    ASSERT_FALSE(src.is_ok());
    EXPECT_NE(src.status().message().find("empty sequence"), std::string::npos);
  }
  {
    TempDir d;
    make_folder(d);
    write_text(d / "camera.toml", "[camera]\nwidth = 64\nfx = -3\n");
    auto src = replay::TumSource::open(d.path.string(), replay::TumReplayConfig{});
    ASSERT_FALSE(src.is_ok());
    EXPECT_NE(src.status().message().find("camera.toml:3: camera.fx"), std::string::npos)
        << src.status().message();
  }
}

// A small PNG that declares a huge image is refused on its header, before OpenCV allocates for it:
// against camera.toml's size, and in a folder without one against a sane bound.
TEST(TumFolder, PngDeclaringAHugeImageIsRefusedBeforeDecoding) {
  std::string bomb = std::string("\x89PNG\r\n\x1a\n", 8) + std::string("\0\0\0\x0dIHDR", 8);
  for (int shift : {24, 16, 8, 0}) bomb += static_cast<char>((30000u >> shift) & 0xff);
  for (int shift : {24, 16, 8, 0}) bomb += static_cast<char>((30000u >> shift) & 0xff);
  bomb += std::string("\x10\0\0\0", 4) + std::string(1 << 16, 'x');
  for (bool with_camera : {true, false}) {
    TempDir d;
    make_folder(d);
    if (!with_camera) fs::remove(d / "camera.toml");
    std::ofstream(d / "depth/1.000000.png", std::ios::binary | std::ios::trunc) << bomb;
    auto src = replay::TumSource::open(d.path.string(), replay::TumReplayConfig{});
    Status st = src.is_ok() ? (*src)->next().status() : src.status();
    EXPECT_EQ(st.code(), StatusCode::kCorrupt) << with_camera << ": " << st.to_string();
    EXPECT_NE(st.message().find("declares 30000x30000"), std::string::npos) << st.message();
  }
}

TEST(TumFolder, AssociatesPosesByNearestTimestamp) {
  TempDir d;
  make_folder(d);
  write_text(d / "groundtruth.txt", "0.990 1 2 3 0 0 0 1\n1.040 4 5 6 0 0 0 1\n");
  replay::TumReplayConfig c;
  c.use_groundtruth = true;
  auto src = replay::TumSource::open(d.path.string(), c);
  ASSERT_TRUE(src.is_ok());
  auto f0 = (*src)->next();
  auto f1 = (*src)->next();
  ASSERT_TRUE(f0->T_world_cam_hint && f1->T_world_cam_hint);
  EXPECT_DOUBLE_EQ(f0->T_world_cam_hint->translation().x(), 1.0);
  EXPECT_DOUBLE_EQ(f1->T_world_cam_hint->translation().x(), 4.0);
}
