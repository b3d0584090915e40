// Replays a TUM RGB-D folder: depth.txt / rgb.txt, 16-bit PNG depth, PNG or JPEG colour, an
// optional trajectory as the pose source, and the camera from camera.toml, the caller, or the
// image size. Every file is read only if it is a regular file (input_file.hpp).
#pragma once

#include <atomic>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "depthfuse/app_config.hpp"
#include "depthfuse/frame_source.hpp"
#include "depthfuse/replay/undistort.hpp"

namespace depthfuse::replay {

struct CameraFile {
  CameraIntrinsics intrinsics;
  double depth_scale = 5000.0;  // PNG value per metre
  // The recorded images' lens distortion, undone as each frame is read; none if no key is given.
  std::optional<LensDistortion> distortion;
  // Added to every colour image's stamp before it is paired with the depth frame nearest in time.
  // Two unsynchronised streams stamp their images with different delays after the exposure: on
  // TUM fr1 the colour image stamped t was taken with the depth frame stamped t + 20 ms, and pairing
  // by stamp alone gave each depth frame the colour of the next exposure.
  double color_stamp_offset_s = 0.0;
};

// Reads a camera.toml ([camera] width height fx fy cx cy depth_scale, optional row_readout_s,
// k1 k2 p1 p2 k3 and color_stamp_offset_s); errors name key and line.
Result<CameraFile> read_camera_file(const std::string& path);

struct TumReplayConfig {
  std::optional<CameraIntrinsics> intrinsics;  // overrides camera.toml and the defaults
  std::optional<double> depth_scale;           // PNG value per metre; default camera.toml or 5000
  // With `intrinsics`: the images' lens distortion (camera.toml's is not read then).
  std::optional<LensDistortion> distortion;
  // CameraFile::color_stamp_offset_s; default camera.toml's, or 0.
  std::optional<double> color_stamp_offset_s;
  std::string poses_path;                      // trajectory giving T_world_cam_hint; "" = none
  bool use_groundtruth = false;                // poses from <folder>/groundtruth.txt if present
  double max_association_dt_s = 0.02;          // rgb and poses matched to depth within this
  bool load_color = true;
  size_t max_frames = 0;                       // 0 = all
  size_t stride = 1;                           // use every n-th depth frame
};

class TumSource : public FrameSource {
 public:
  static Result<std::unique_ptr<TumSource>> open(const std::string& folder,
                                                 const TumReplayConfig& config);

  Result<Frame> next() override;
  std::string describe() const override;
  std::optional<double> nominal_rate_hz() const override;
  std::optional<size_t> frame_count() const override { return entries_.size(); }
  Status rewind() override {
    next_ = 0;
    return Status::ok();
  }

  // Frame i without advancing (batch tools).
  Result<Frame> load(size_t i) const;
  const CameraIntrinsics& intrinsics() const { return intrinsics_; }
  double depth_scale() const { return depth_scale_; }
  // The lens distortion undone on every frame, if any.
  const std::optional<Undistorter>& undistorter() const { return undistort_; }
  // Where the intrinsics came from: "camera.toml", "caller", "TUM freiburg default", ...
  const std::string& intrinsics_origin() const { return intrinsics_origin_; }
  bool has_poses() const { return has_poses_; }
  double timestamp_s(size_t i) const { return entries_[i].t_depth; }

 private:
  struct Entry {
    double t_depth = 0;
    std::string depth_path;
    std::string rgb_path;                 // empty: none associated
    std::optional<Pose> T_world_cam;      // from the trajectory
  };
  std::string folder_;
  std::vector<Entry> entries_;
  CameraIntrinsics intrinsics_;
  std::string intrinsics_origin_;
  double depth_scale_ = 5000.0;
  std::optional<Undistorter> undistort_;  // the lens undone; none: as recorded
  // Per pixel of a frame, the recorded pixel it is read from (undistort_'s lookup, or the identity):
  // depth and colour are read by one loop each, whatever the lens.
  std::vector<int32_t> pixel_source_;
  bool has_poses_ = false;
  size_t next_ = 0;
  mutable std::atomic<bool> warned_color_size_{false};  // load() said colour was another size
};

// For the source factory: arg is the folder.
Result<std::unique_ptr<FrameSource>> open_tum_source(const std::string& arg, const AppConfig& config);

}  // namespace depthfuse::replay
