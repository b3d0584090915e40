// One frame's path through a scan, the same for the fusion daemon (ScanSession) and for the
// offline tools (track_sequence, `depthfuse reconstruct --track`): so that a figure measured
// offline is a figure of the code the rig runs.
//
//   predict   the motion model's pose at the frame's time (none with a hint), once
//   prepare   the map as the frame will see it, around the initial pose (a pager loads the
//             evicted chunks there)
//   process   IncrementalReconstructor::process from that prediction: measure, register, fuse
//   record    a fused frame's pose, keyframes and paging (the scan file)
//
// The caller publishes what it needs of the report.
#pragma once

#include <optional>

#include "depthfuse/incremental.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse {

// What keeps a scan around the method: the checkpoint store and its pager (the daemon's), or
// nothing (offline tracking). Called from the frame path's thread only.
class FrameStore {
 public:
  virtual ~FrameStore() = default;
  // Before process(): the map as the frame will see it from `T_world_cam_initial`
  // (IncrementalReconstructor::initial_pose).
  virtual Status prepare_frame(const Frame& frame, const Pose& T_world_cam_initial,
                               IncrementalReconstructor& reconstructor) = 0;
  // After process(), for a frame that was fused.
  virtual Status frame_fused(const Frame& frame, const FrameReport& report,
                             IncrementalReconstructor& reconstructor) = 0;
};

struct FrameOutcome {
  FrameReport report;
  // The first failure of the store's calls: the frame was processed all the same (a full disk
  // must not stop the scan), and the caller reports it.
  Status store_status;
};

class FramePath {
 public:
  // `store` may be null: nothing is paged or recorded.
  FramePath(IncrementalReconstructor& reconstructor, FrameStore* store = nullptr)
      : reconstructor_(reconstructor), store_(store) {}

  // A failure of process() itself (a frame that cannot be measured) is the error; the store's are
  // in the outcome.
  Result<FrameOutcome> run(const Frame& frame);

 private:
  IncrementalReconstructor& reconstructor_;
  FrameStore* store_;
};

}  // namespace depthfuse
