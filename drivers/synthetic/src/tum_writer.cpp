// A synthetic sequence written as a TUM RGB-D folder (see tum_writer.hpp for the layout).
#include "depthfuse/synthetic/tum_writer.hpp"

#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <string>
#include <system_error>

#include "toml_write.hpp"

namespace depthfuse::synthetic {

namespace fs = std::filesystem;

namespace {

Status write_text(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) return io_error("cannot create '" + path.string() + "'");
  out << text;
  out.close();
  if (!out) return io_error("cannot write '" + path.string() + "'");
  return Status::ok();
}

Status write_png(const fs::path& path, const cv::Mat& image) {
  try {
    if (!cv::imwrite(path.string(), image))
      return io_error("cannot write PNG '" + path.string() + "'");
  } catch (const cv::Exception& e) {
    return io_error("cannot write PNG '" + path.string() + "': " + e.what());
  }
  return Status::ok();
}

std::string pose_line(const std::string& stamp, const Pose& T) {
  Eigen::Quaterniond q(T.linear());
  q.normalize();
  if (q.w() < 0.0) q.coeffs() *= -1.0;  // one of the two equivalent signs, always the same
  const Eigen::Vector3d t = T.translation();
  char buf[256];
  std::snprintf(buf, sizeof(buf), "%s %.9f %.9f %.9f %.9f %.9f %.9f %.9f\n", stamp.c_str(), t.x(),
                t.y(), t.z(), q.x(), q.y(), q.z(), q.w());
  return buf;
}

std::string readme(const SyntheticSequence& seq, bool with_color) {
  const SyntheticConfig& c = seq.config();
  std::string s =
      "Synthetic depth sequence written by depthfuse (synthetic frame source).\n"
      "\n"
      "Scene: " +
      std::string(to_string(c.scene)) + ", " + std::to_string(seq.size()) + " frames at " +
      std::to_string(c.rate_hz) + " Hz, seed " + std::to_string(c.seed) +
      ".\n"
      "Layout (TUM RGB-D conventions):\n"
      "  depth/<timestamp>.png  16-bit depth, value = metres * 5000, 0 = no measurement\n";
  if (with_color)
    s += "  rgb/<timestamp>.png    8-bit colour registered to depth pixel for pixel\n"
         "  rgb.txt                timestamp and file of every colour image\n";
  s += "  depth.txt              timestamp and file of every depth image\n"
       "  groundtruth.txt        true camera poses: timestamp tx ty tz qx qy qz qw (camera to "
       "world,\n"
       "                         optical frame: x right, y down, z forward)\n"
       "  poses_perturbed.txt    the poses a structure-from-motion front end would give (true "
       "poses\n"
       "                         with noise, see [generator] pose_noise_m / pose_noise_deg)\n"
       "  camera.toml            pinhole intrinsics of the depth images and the depth scale\n"
       "  scene.toml             the analytic scene (exact ground truth surfaces) and the "
       "generator\n"
       "                         settings that reproduce this folder\n"
       "Depth carries simulated Kinect V2 time-of-flight noise (axial noise after Fankhauser et "
       "al.\n"
       "2015, flying pixels, multipath bias in concave corners, dropouts, outliers) unless\n"
       "[generator.noise] enabled = false.\n";
  return s;
}

}  // namespace

std::string tum_timestamp(int64_t utime) {
  const bool negative = utime < 0;
  const uint64_t a =
      negative ? static_cast<uint64_t>(-(utime + 1)) + 1 : static_cast<uint64_t>(utime);
  char buf[48];
  std::snprintf(buf, sizeof(buf), "%s%" PRIu64 ".%06" PRIu64, negative ? "-" : "", a / 1000000u,
                a % 1000000u);
  return buf;
}

Status write_tum_folder(const SyntheticSequence& sequence, const std::string& folder,
                        bool with_color) {
  const fs::path root(folder);
  std::error_code ec;
  for (const fs::path& dir : {root, root / "depth", root / "rgb"}) {
    if (dir == root / "rgb" && !with_color) continue;
    fs::create_directories(dir, ec);
    if (ec) return io_error("cannot create folder '" + dir.string() + "': " + ec.message());
  }

  const CameraIntrinsics& K = sequence.config().intrinsics;
  std::string depth_list = "# depth maps\n# file: 'depthfuse synthetic " +
                           std::string(to_string(sequence.config().scene)) +
                           "'\n# timestamp filename\n";
  std::string rgb_list = "# color images\n# file: 'depthfuse synthetic " +
                         std::string(to_string(sequence.config().scene)) +
                         "'\n# timestamp filename\n";
  std::string truth =
      "# ground truth trajectory (camera to world)\n# timestamp tx ty tz qx qy qz qw\n";
  std::string perturbed =
      "# perturbed trajectory (camera to world), as a structure-from-motion front end would give "
      "it\n"
      "# timestamp tx ty tz qx qy qz qw\n";

  Frame frame;
  cv::Mat depth16(K.height, K.width, CV_16UC1);
  cv::Mat bgr(K.height, K.width, CV_8UC3);
  for (size_t i = 0; i < sequence.size(); ++i) {
    sequence.render_into(i, true, &frame, with_color);
    const std::string stamp = tum_timestamp(frame.utime);
    for (int v = 0; v < K.height; ++v) {
      uint16_t* row = depth16.ptr<uint16_t>(v);
      for (int u = 0; u < K.width; ++u) {
        const double z = frame.depth.at(u, v);
        const double value = std::round(z * kTumDepthScale);
        row[u] = static_cast<uint16_t>(z > 0.0 ? std::fmin(std::fmax(value, 0.0), 65535.0) : 0.0);
      }
    }
    const std::string depth_rel = "depth/" + stamp + ".png";
    DF_RETURN_IF_ERROR(write_png(root / depth_rel, depth16));
    depth_list += stamp + " " + depth_rel + "\n";
    if (with_color) {
      for (int v = 0; v < K.height; ++v) {
        uint8_t* row = bgr.ptr<uint8_t>(v);
        const uint8_t* src = &frame.color.rgb[static_cast<size_t>(v) * K.width * 3];
        for (int u = 0; u < K.width; ++u) {
          row[3 * u + 0] = src[3 * u + 2];
          row[3 * u + 1] = src[3 * u + 1];
          row[3 * u + 2] = src[3 * u + 0];
        }
      }
      const std::string rgb_rel = "rgb/" + stamp + ".png";
      DF_RETURN_IF_ERROR(write_png(root / rgb_rel, bgr));
      rgb_list += stamp + " " + rgb_rel + "\n";
    }
    truth += pose_line(stamp, sequence.T_world_cam_true(i));
    perturbed += pose_line(stamp, sequence.T_world_cam_perturbed(i));
  }

  DF_RETURN_IF_ERROR(write_text(root / "depth.txt", depth_list));
  if (with_color) DF_RETURN_IF_ERROR(write_text(root / "rgb.txt", rgb_list));
  DF_RETURN_IF_ERROR(write_text(root / "groundtruth.txt", truth));
  DF_RETURN_IF_ERROR(write_text(root / "poses_perturbed.txt", perturbed));

  namespace tw = toml_write;
  const std::string camera_text =
      "# Pinhole intrinsics of the depth images (undistorted); depth_scale = PNG value per metre.\n"
      "[camera]\nwidth = " +
      std::to_string(K.width) + "\nheight = " + std::to_string(K.height) +
      "\nfx = " + tw::format_double(K.fx) + "\nfy = " + tw::format_double(K.fy) +
      "\ncx = " + tw::format_double(K.cx) + "\ncy = " + tw::format_double(K.cy) +
      "\ndepth_scale = " + tw::format_double(kTumDepthScale) + "\n";
  DF_RETURN_IF_ERROR(write_text(root / "camera.toml", camera_text));
  DF_RETURN_IF_ERROR(
      write_text(root / "scene.toml",
                 sequence.scene().to_toml() + "\n" + synthetic_config_to_toml(sequence.config())));
  DF_RETURN_IF_ERROR(write_text(root / "README.txt", readme(sequence, with_color)));
  return Status::ok();
}

}  // namespace depthfuse::synthetic
