// Internal: point-to-plane ICP of one keyframe's points against another's (KeyframeCloud), for
// verifying a loop closure. Both clouds are small (a keyframe's points averaged in cubes): the
// target's points are found through a hash grid of cubes the size of the correspondence gate, so a
// query looks at 27 cubes whatever the clouds' extent.
#pragma once

#include <cstddef>

#include "depthfuse/config.hpp"
#include "depthfuse/pose_delta.hpp"
#include "depthfuse/scan_graph.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse {

struct CloudAlignment {
  bool converged = false;
  Pose T_target_source = Pose::Identity();
  size_t pairs = 0;
  double overlap = 0;  // pairs / source points
  double rmse_m = 0;
  // Of the source's pose in the target's frame, as a right perturbation (pose_delta.hpp): the
  // normal equations less the share the normals' noise makes, over the variance of a pair (the
  // residual's, and config.model_error_m's).
  Matrix6d information = Matrix6d::Zero();
  // The same with the normals' noise left in: the curvature the ICP itself followed.
  Matrix6d followed_information = Matrix6d::Zero();
};

// Coarse to fine from T_target_source_initial: gates of 4, 2 and 1 times
// config.max_correspondence_m, normals within 35 degrees.
CloudAlignment align_clouds(const KeyframeCloud& source, const KeyframeCloud& target,
                            const Pose& T_target_source_initial, const LoopClosureConfig& config);

}  // namespace depthfuse
