// File formats and bad input: PLY, TUM trajectories, TUM folders.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>

#include "depthfuse/input_file.hpp"
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

// Issue 36: inputs are opened only when they are regular files; a FIFO (which would block the
// open until a writer comes), a directory or a device is refused with a message naming it.
TEST(InputFile, OnlyARegularFileIsOpened) {
  TempDir d;
  write_text(d / "ok.txt", "hello\n");
  auto text = read_input_file(d / "ok.txt", "list", 100);
  ASSERT_TRUE(text.is_ok()) << text.status().to_string();
  EXPECT_EQ(*text, "hello\n");
  auto large = read_input_file(d / "ok.txt", "list", 5);
  EXPECT_EQ(large.status().message(), "list " + (d / "ok.txt") + " is 6 bytes; a list is at most 5");
  EXPECT_EQ(read_input_file(d / "none", "list", 100).status().code(), StatusCode::kNotFound);

  ASSERT_EQ(::mkfifo((d / "fifo").c_str(), 0600), 0);
  const auto started = std::chrono::steady_clock::now();
  for (const auto& [path, kind] : {std::pair{d / "fifo", "a FIFO"}, std::pair{d.path.string(), "a directory"},
                                   std::pair{std::string("/dev/null"), "a character device"}}) {
    const Status st = check_input_file(path, "cloud");
    EXPECT_EQ(st.code(), StatusCode::kInvalidArgument);
    EXPECT_EQ(st.message(), "cloud " + path + " is " + kind + ", not a regular file");
    EXPECT_EQ(read_input_file(path, "trajectory", 100).status().message(),
              "trajectory " + path + " is " + kind + ", not a regular file");
  }
  // The readers of each format go through it.
  EXPECT_NE(read_ply(d / "fifo").status().message().find("is a FIFO"), std::string::npos);
  EXPECT_NE(read_tum_trajectory(d / "fifo").status().message().find("is a FIFO"), std::string::npos);
  EXPECT_LT(std::chrono::steady_clock::now() - started, std::chrono::seconds(5));
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

// Lens distortion in camera.toml (k1 k2 p1 p2 k3, OpenCV's model): the replay undoes it, so that a
// plane recorded through a distorting lens comes back as the same plane, every pixel on its own ray.
namespace {

// TUM fr1's colour camera, to which its depth images are registered, scaled to 160 x 120 (the same
// field of view, so the same distortion at the edges).
CameraIntrinsics small_fr1() { return {160, 120, 517.3 / 4, 516.5 / 4, 318.6 / 4, 255.3 / 4}; }
replay::LensDistortion fr1_rgb() { return {0.2624, -0.9531, -0.0054, 0.0026, 1.1633}; }

std::string camera_toml(const CameraIntrinsics& K, const std::string& extra) {
  std::ostringstream s;
  s.precision(17);
  s << "[camera]\nwidth = " << K.width << "\nheight = " << K.height << "\nfx = " << K.fx
    << "\nfy = " << K.fy << "\ncx = " << K.cx << "\ncy = " << K.cy << "\n" << extra;
  return s.str();
}

std::string distortion_keys(const replay::LensDistortion& d) {
  std::ostringstream s;
  s.precision(17);
  s << "k1 = " << d.k1 << "\nk2 = " << d.k2 << "\np1 = " << d.p1 << "\np2 = " << d.p2
    << "\nk3 = " << d.k3 << "\n";
  return s.str();
}

// The plane n . X = 2 m, tilted 17 and 11 degrees off the optical axis: its depth on the ray
// through normalised (x, y).
double plane_depth(double x, double y) {
  const Eigen::Vector3d n = Eigen::Vector3d(0.3, -0.2, 1.0).normalized();
  return 2.0 / n.dot(Eigen::Vector3d(x, y, 1.0));
}

// One frame of that plane as a camera with distortion d records it: each recorded pixel's ray is
// found by OpenCV's own inversion of the model.
void write_distorted_plane(const TempDir& d, const CameraIntrinsics& K,
                           const replay::LensDistortion& dist) {
  fs::create_directories(d / "depth");
  std::vector<cv::Point2f> pixels;
  for (int v = 0; v < K.height; ++v)
    for (int u = 0; u < K.width; ++u) pixels.emplace_back(u, v);
  std::vector<cv::Point2f> rays;
  const cv::Matx33d camera(K.fx, 0, K.cx, 0, K.fy, K.cy, 0, 0, 1);
  cv::undistortPoints(pixels, rays, camera, cv::Vec<double, 5>(dist.k1, dist.k2, dist.p1, dist.p2, dist.k3),
                      cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 100, 1e-12));
  cv::Mat img(K.height, K.width, CV_16UC1);
  for (int v = 0; v < K.height; ++v)
    for (int u = 0; u < K.width; ++u) {
      const cv::Point2f r = rays[static_cast<size_t>(v) * K.width + u];
      img.at<uint16_t>(v, u) = static_cast<uint16_t>(std::lround(plane_depth(r.x, r.y) * 5000));
    }
  cv::imwrite(d / "depth/1.000000.png", img);
  write_text(d / "depth.txt", "1.000000 depth/1.000000.png\n");
}

struct PlaneError {
  double rms_m = 0, worst_m = 0;
  size_t valid = 0;
};

// Each pixel's depth against the plane's on that pixel's own (pinhole) ray.
PlaneError plane_error(const Frame& f, const CameraIntrinsics& K) {
  PlaneError e;
  double sum = 0;
  for (int v = 0; v < K.height; ++v)
    for (int u = 0; u < K.width; ++u) {
      const float z = f.depth.at(u, v);
      if (z <= 0) continue;
      const double err = z - plane_depth((u - K.cx) / K.fx, (v - K.cy) / K.fy);
      sum += err * err;
      e.worst_m = std::max(e.worst_m, std::abs(err));
      ++e.valid;
    }
  e.rms_m = e.valid ? std::sqrt(sum / e.valid) : 0;
  return e;
}

}  // namespace

TEST(TumFolder, LensDistortionIsUndoneOnDepth) {
  TempDir d;
  const CameraIntrinsics K = small_fr1();
  write_distorted_plane(d, K, fr1_rgb());
  write_text(d / "camera.toml", camera_toml(K, distortion_keys(fr1_rgb())));
  auto src = replay::TumSource::open(d.path.string(), replay::TumReplayConfig{});
  ASSERT_TRUE(src.is_ok()) << src.status().to_string();
  ASSERT_TRUE((*src)->undistorter().has_value());
  auto f = (*src)->next();
  ASSERT_TRUE(f.is_ok()) << f.status().to_string();
  const PlaneError undone = plane_error(*f, K);

  // The same recording read as if its lens had none: what depthfuse did before.
  replay::TumReplayConfig as_recorded;
  as_recorded.intrinsics = K;
  auto raw_src = replay::TumSource::open(d.path.string(), as_recorded);
  ASSERT_TRUE(raw_src.is_ok()) << raw_src.status().to_string();
  EXPECT_FALSE((*raw_src)->undistorter().has_value());
  auto raw = (*raw_src)->next();
  ASSERT_TRUE(raw.is_ok());
  const PlaneError ignored = plane_error(*raw, K);

  // Nearest pixel: a sample is at most half a pixel off in u and in v, and the plane's depth
  // changes by up to 8.3 mm a pixel in u and 5.6 in v (at its far side, 2.8 m away at the left
  // edge); plus the PNG's 0.2 mm step. Ignoring the lens puts the edges' depths several pixels'
  // worth off.
  EXPECT_GT(undone.valid, 0.9 * K.width * K.height);  // the corners' rays left the recorded image
  EXPECT_LT(undone.rms_m, 0.0025) << "worst " << undone.worst_m;
  EXPECT_LT(undone.worst_m, 0.5 * (0.0083 + 0.0056) + 0.0002);
  EXPECT_GT(ignored.rms_m, 3 * undone.rms_m) << "worst " << ignored.worst_m;
  EXPECT_GT(ignored.worst_m, 0.02);
}

TEST(TumFolder, LensDistortionMapsEachPixelToItsRaysSample) {
  // Against OpenCV's own map: every undistorted pixel reads the recorded pixel nearest to where
  // cv::initUndistortRectifyMap says its ray landed.
  const CameraIntrinsics K = small_fr1();
  const replay::LensDistortion dist = fr1_rgb();
  auto u = replay::Undistorter::create(K, dist);
  ASSERT_TRUE(u.is_ok()) << u.status().to_string();
  cv::Mat map_x, map_y;
  const cv::Matx33d camera(K.fx, 0, K.cx, 0, K.fy, K.cy, 0, 0, 1);
  cv::initUndistortRectifyMap(camera, cv::Vec<double, 5>(dist.k1, dist.k2, dist.p1, dist.p2, dist.k3),
                              cv::noArray(), camera, cv::Size(K.width, K.height), CV_32FC1, map_x,
                              map_y);
  size_t outside = 0;
  for (int v = 0; v < K.height; ++v)
    for (int c = 0; c < K.width; ++c) {
      const int32_t s = u->source()[static_cast<size_t>(v) * K.width + c];
      const float x = map_x.at<float>(v, c), y = map_y.at<float>(v, c);
      const bool inside = x > -0.5f && x < K.width - 0.5f && y > -0.5f && y < K.height - 0.5f;
      if (s == replay::Undistorter::kOutside) {
        ++outside;
        EXPECT_FALSE(x > 0.01f && x < K.width - 1.01f && y > 0.01f && y < K.height - 1.01f)
            << "pixel (" << c << ", " << v << ") has a sample at " << x << ", " << y;
        continue;
      }
      ASSERT_TRUE(inside) << c << ", " << v;
      EXPECT_LE(std::abs(s % K.width - x), 0.501f) << c << ", " << v;
      EXPECT_LE(std::abs(s / K.width - y), 0.501f) << c << ", " << v;
    }
  EXPECT_GT(outside, 0u);  // fr1's lens pushes the corners' rays out of the image
  EXPECT_GT(u->max_shift_px(), 3.0);
}

TEST(TumFolder, AbsurdLensDistortionIsRefused) {
  const CameraIntrinsics K = small_fr1();
  struct Case {
    replay::LensDistortion d;
    const char* expected;
  };
  for (const Case& c : {
           // r (1 - 2 r^2) turns back at r = 0.41, inside the image: a fold.
           Case{{-2.0, 0, 0, 0, 0}, "folds over along"},
           // Monotonic, but the corners move by 30 px of a 200 px diagonal.
           Case{{0.5, 0, 0, 0, 0}, "moves pixels by up to"},
           // fr1's coefficients in the wrong order (k1 k2 k3 p1 p2): k3 as p1.
           Case{{0.2624, -0.9531, 1.1633, -0.0054, 0.0026}, "folds over along"},
       }) {
    auto u = replay::Undistorter::create(K, c.d);
    ASSERT_FALSE(u.is_ok()) << c.expected;
    EXPECT_NE(u.status().message().find(c.expected), std::string::npos) << u.status().message();
    // From a camera file: refused when it is read, naming the file.
    TempDir d;
    make_folder(d);
    write_text(d / "camera.toml", camera_toml(K, distortion_keys(c.d)));
    auto cam = replay::read_camera_file(d / "camera.toml");
    ASSERT_FALSE(cam.is_ok());
    EXPECT_NE(cam.status().message().find("camera.toml: camera.k1..k3: lens distortion"),
              std::string::npos)
        << cam.status().message();
    // Given by the caller: refused when the folder is opened.
    replay::TumReplayConfig rc;
    rc.intrinsics = K;
    rc.distortion = c.d;
    write_text(d / "camera.toml", camera_toml(K, ""));
    auto src = replay::TumSource::open(d.path.string(), rc);
    ASSERT_FALSE(src.is_ok());
    EXPECT_NE(src.status().message().find(c.expected), std::string::npos) << src.status().message();
  }
  // No keys: no distortion, and nothing is remapped.
  TempDir d;
  make_folder(d);
  auto cam = replay::read_camera_file(d / "camera.toml");
  ASSERT_TRUE(cam.is_ok());
  EXPECT_FALSE(cam->distortion.has_value());
  write_text(d / "camera.toml", camera_toml(small_fr1(), "k1 = 0.1\n"));
  cam = replay::read_camera_file(d / "camera.toml");
  ASSERT_TRUE(cam.is_ok()) << cam.status().to_string();
  ASSERT_TRUE(cam->distortion.has_value());
  EXPECT_EQ(cam->distortion->k1, 0.1);
  EXPECT_EQ(cam->distortion->k3, 0.0);
}
