// Plain data shared by every part of depthfuse: intrinsics, depth and colour images, frames, poses.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace depthfuse {

using Pose = Eigen::Isometry3d;  // always named T_<to>_<from>, e.g. T_world_cam maps camera to world

// Pinhole intrinsics of the depth camera, in pixels. Depth images are undistorted.
struct CameraIntrinsics {
  int width = 512;
  int height = 424;
  double fx = 365.0;
  double fy = 365.0;
  double cx = 255.5;
  double cy = 211.5;
  // Rolling shutter: the time from the first row's exposure to the last one's, s; 0 for a global
  // shutter (the Kinect V2's time-of-flight camera). Rows are taken top to bottom; the frame's
  // stamp and pose are those of its middle row. A Kinect v1 reads its rows over about a frame
  // period (TUM fr1: 0.03 s, docs/history/results-sessions-1-33.md).
  double row_readout_s = 0.0;

  bool valid() const { return width > 0 && height > 0 && fx > 0 && fy > 0; }
  // Why these values, though they parse, are no camera's (they would give an empty cloud), or
  // nothing: focal lengths of 0.1 to 100 image widths (a field of view of about 160 to 0.6
  // degrees), the principal point inside the image. Starts with the fields it names ("fx, fy").
  std::optional<std::string> physical_problem() const;
  // Kinect V2 depth camera nominal values (see config/depthfuse.toml for the source).
  static CameraIntrinsics kinect_v2() { return {}; }
};

// Depth in metres, row-major, 0 where there is no measurement.
struct DepthImage {
  int width = 0;
  int height = 0;
  std::vector<float> depth_m;

  DepthImage() = default;
  DepthImage(int w, int h) : width(w), height(h), depth_m(static_cast<size_t>(w) * h, 0.0f) {}
  bool empty() const { return depth_m.empty(); }
  float at(int u, int v) const { return depth_m[static_cast<size_t>(v) * width + u]; }
  float& at(int u, int v) { return depth_m[static_cast<size_t>(v) * width + u]; }
};

// 8-bit RGB, row-major, registered to the depth image pixel for pixel (same size), or empty.
struct ColorImage {
  int width = 0;
  int height = 0;
  std::vector<uint8_t> rgb;  // 3 bytes per pixel
  bool empty() const { return rgb.empty(); }
};

// One capture, as every FrameSource delivers it.
struct Frame {
  int64_t utime = 0;          // capture time, microseconds since the Unix epoch (or sequence time)
  uint32_t sequence = 0;      // monotonically increasing per source, gaps mean lost frames
  std::string sensor_serial;  // empty when unknown
  CameraIntrinsics intrinsics;
  DepthImage depth;
  ColorImage color;                            // optional
  std::optional<Pose> T_world_cam_hint;        // e.g. motion capture, odometry or a trajectory file
};

// A camera pose with its time, as in a TUM trajectory file.
struct StampedPose {
  double timestamp_s = 0.0;
  Pose T_world_cam = Pose::Identity();
};

}  // namespace depthfuse
