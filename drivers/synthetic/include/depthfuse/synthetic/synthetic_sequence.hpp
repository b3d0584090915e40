// A synthetic capture: a built-in scene, a camera trajectory through it, true and perturbed poses,
// and frames rendered on demand with Kinect V2 geometry and noise. Deterministic by seed.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

#include "depthfuse/status.hpp"
#include "depthfuse/synthetic/noise_model.hpp"
#include "depthfuse/synthetic/renderer.hpp"
#include "depthfuse/synthetic/scene.hpp"
#include "depthfuse/synthetic/trajectory.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::synthetic {

struct SyntheticConfig {
  SceneKind scene = SceneKind::kCorner;
  int frames = 60;
  uint64_t seed = 1;  // scene layout, sensor noise and pose perturbation all derive from it
  // Pose perturbation, as a structure-from-motion front end would hand poses over. Each frame
  // independently: the camera centre moves by a translation whose x, y and z are each
  // N(0, pose_noise_m^2) in the world frame (so the RMS distance is sqrt(3) * pose_noise_m), and
  // the camera turns about its centre by an angle N(0, pose_noise_deg^2) about a uniformly random
  // axis.
  double pose_noise_m = 0.0;
  double pose_noise_deg = 0.0;
  CameraIntrinsics intrinsics = CameraIntrinsics::kinect_v2();
  NoiseConfig noise;
  double rate_hz = 30.0;
  double min_depth_m = 0.5;  // sensor range (Kinect V2)
  double max_depth_m = 4.5;
  // Whether frames carry the perturbed pose as T_world_cam_hint; without, a consumer tracks them
  // as it does a Kinect's. Not part of the [generator] table: the written folder has the poses.
  bool pose_hints = true;
  // The first frame a SyntheticSource streams: a stretch of a long walk on its own, to look at one
  // place of a 20-minute scan without the frames before it. Not part of the [generator] table.
  int first_frame = 0;

  Status validate() const;
};

// The length a scene's walk is made for, when none is asked: 60 frames; for the lap walks
// (furnished, plain) 1,200, two laps and back past the start.
int default_frames(SceneKind kind);

// The [generator] table that write_tum_folder puts in scene.toml, and back.
std::string synthetic_config_to_toml(const SyntheticConfig& config);
// Reads a [generator] table (keys left out keep their defaults; unknown keys are errors).
Result<SyntheticConfig> parse_synthetic_config_toml(const std::string& text,
                                                    const std::string& origin = "scene.toml");

class SyntheticSequence {
 public:
  static Result<SyntheticSequence> create(const SyntheticConfig& config);

  size_t size() const { return static_cast<size_t>(config_.frames); }

  // Poses are computed on demand in O(1) (a 20-minute walk keeps no table), hence by value.
  Pose T_world_cam_true(size_t i) const { return trajectory_.T_world_cam(i); }
  Pose T_world_cam_perturbed(size_t i) const;

  // utime = round(i / rate_hz * 1e6) microseconds ("sequence time", starting at 0).
  int64_t utime(size_t i) const;

  // Frame i (i < size()): utime, sequence = i, sensor_serial "synthetic", intrinsics, depth in
  // metres, a colour image registered to it, and T_world_cam_hint = the perturbed pose. with_noise
  // = false gives the exact depth (still gated to the sensor range). No hint when
  // config().pose_hints is false. Thread-safe.
  Frame render(size_t i, bool with_noise = true) const;
  // The same into an existing frame, reusing its buffers (benchmarks at 30 Hz).
  void render_into(size_t i, bool with_noise, Frame* frame, bool with_color = true) const;

  const Scene& scene() const { return *scene_; }
  const SyntheticConfig& config() const { return config_; }
  const Trajectory& trajectory() const { return trajectory_; }
  const DepthRenderer& renderer() const { return renderer_; }

 private:
  SyntheticConfig config_;
  std::shared_ptr<const Scene> scene_;
  Trajectory trajectory_;
  DepthRenderer renderer_;
};

// Perturbs a pose as SyntheticConfig documents; `key` selects the random draw (deterministic).
Pose perturb_pose(const Pose& T_world_cam, double noise_m, double noise_deg, uint64_t key);

}  // namespace depthfuse::synthetic
