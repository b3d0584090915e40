// A synthetic scan rendered once for a test suite: its frames, the perturbed poses a structure-from-
// motion front end would hand over, and the true poses.
#pragma once

#include <vector>

#include "depthfuse/synthetic/synthetic_sequence.hpp"

namespace depthfuse::test {

// The perturbation: poses about 2 cm and 1 degree off, as a structure-from-motion front end
// would hand them over.
inline synthetic::SyntheticConfig perturbed_scan(synthetic::SceneKind scene, int frames,
                                                 uint64_t seed) {
  synthetic::SyntheticConfig c;
  c.scene = scene;
  c.frames = frames;
  c.seed = seed;
  c.pose_noise_m = 0.02;
  c.pose_noise_deg = 1.0;
  return c;
}

// The furnished room's walk as the room-scale benchmark scans it: its layout depends on the walk's
// length, so the benchmark's 1,200 frames and seed 1.
inline Result<synthetic::SyntheticSequence> furnished_walk() {
  synthetic::SyntheticConfig c;
  c.scene = synthetic::SceneKind::kFurnished;
  c.frames = 1200;
  c.seed = 1;
  return synthetic::SyntheticSequence::create(c);
}

struct RenderedScan {
  std::vector<Frame> frames;
  std::vector<Pose> perturbed, truth;

  static RenderedScan of(const synthetic::SyntheticSequence& seq) {
    RenderedScan s;
    for (size_t i = 0; i < seq.size(); ++i) {
      s.frames.push_back(seq.render(i));
      s.perturbed.push_back(seq.T_world_cam_perturbed(i));
      s.truth.push_back(seq.T_world_cam_true(i));
    }
    return s;
  }
};

}  // namespace depthfuse::test
