// Renders depth (and a registered colour image) of a Scene from any camera pose, exact or with the
// time-of-flight noise of NoiseConfig. Stateless apart from its configuration: render() is const
// and may be called from several threads at once. The noise of a view is a pure function of
// `noise_key`, so a (seed, frame) pair always gives the same image, whatever thread renders it.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "depthfuse/synthetic/noise_model.hpp"
#include "depthfuse/synthetic/scene.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::synthetic {

struct RendererConfig {
  CameraIntrinsics intrinsics = CameraIntrinsics::kinect_v2();
  NoiseConfig noise;
  // Sensor range: surfaces nearer or farther than this (measured depth) give no return (0).
  double min_depth_m = 0.5;
  double max_depth_m = 4.5;

  Status validate() const;
};

class DepthRenderer {
 public:
  DepthRenderer() = default;
  DepthRenderer(std::shared_ptr<const Scene> scene, RendererConfig config);

  // Fills depth (metres, 0 = none) and, when `color` is not null, an RGB image registered to it:
  // each surface in its colour with its checker texture (Primitive::checker_m), shaded by a fixed
  // light, whatever the view (black where nothing was hit). The images are resized to the
  // intrinsics.
  void render(const Pose& T_world_cam, uint64_t noise_key, bool with_noise, DepthImage* depth,
              ColorImage* color) const;

  const RendererConfig& config() const { return config_; }
  const Scene& scene() const { return *scene_; }

 private:
  std::shared_ptr<const Scene> scene_;
  RendererConfig config_;
  std::vector<double> checker_per_m_;  // per primitive: 1 / checker_m, 0 = plain
};

}  // namespace depthfuse::synthetic
