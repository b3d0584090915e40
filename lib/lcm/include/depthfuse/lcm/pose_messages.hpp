// The fusion daemon's per-frame messages, assembled from what the frame path reported: pose2_t
// (DEPTHFUSE_POSE2) for every frame processed, and its pose_t (DEPTHFUSE_POSE) for a fused one.
#pragma once

#include <cstdint>
#include <functional>
#include <string>

#include "depthfuse/graph_correction_t.hpp"
#include "depthfuse/incremental.hpp"
#include "depthfuse/scan_graph.hpp"
#include "depthfuse/pose2_t.hpp"
#include "depthfuse/pose_t.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::lcm {

struct FramePublication {
  int64_t frame_publish_utime = 0;  // the depth frame's publish time (capture side), 0 unknown
  std::string scan_id;
  int64_t map_points = 0;           // after the frame
  int64_t publish_utime = 0;        // now
};

// A lost frame carries `T_world_cam_last_placed`, where the camera was last known to be, and no
// fusion counts; a frame whose fusion was shed its own pose and no fusion counts. Neither is
// fused: pose.pose is then not to be published on DEPTHFUSE_POSE.
pose2_t make_pose2(const Frame& frame, const FrameReport& report, const Pose& T_world_cam_last_placed,
                   const FramePublication& publication);

// A loop closure applied before a frame. `sequence_of` gives the sequence of a frame id (its
// keyframes' first frames are frames the daemon fused).
graph_correction_t make_graph_correction(const AppliedCorrection& correction,
                                         const std::function<int64_t(uint32_t)>& sequence_of,
                                         const std::string& sender, const std::string& scan_id,
                                         int64_t utime);

}  // namespace depthfuse::lcm
