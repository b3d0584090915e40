// One frame's path through a scan, the same for the fusion daemon (ScanSession) and for the
// offline tools (track_sequence, `depthfuse reconstruct --track`): so that a figure measured
// offline is a figure of the code the rig runs.
//
//   predict   the motion model's pose at the frame's time (none with a hint), once
//   prepare   the map as the frame will see it, around the initial pose (a pager loads the
//             evicted chunks there)
//   process   IncrementalReconstructor::process from that prediction: measure, register, fuse
//   record    a fused frame's pose, keyframes and paging (the scan file)
//   graph     a frame tracked without a hint joins the pose graph (ScanGraph): a keyframe when the
//             camera has moved far enough (fused frames only), which the loop closer then
//             searches; a correction the
//             loop closer found is applied before the next frame is predicted (the keyframes, the
//             camera's last poses and the map move with it)
//
// The caller publishes what it needs of the report, and moves its own copies of past poses with a
// correction (FrameOutcome::correction).
#pragma once

#include <memory>
#include <optional>

#include "depthfuse/incremental.hpp"
#include "depthfuse/map_deformation.hpp"
#include "depthfuse/scan_graph.hpp"
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
  // After process(), for a frame that was not (tracking lost, or its fusion shed): what
  // prepare_frame() loaded for it must not stay over the budget while the camera is lost for many
  // frames.
  virtual Status frame_not_fused(const FrameReport& report, const Pose& T_world_cam_initial,
                                 IncrementalReconstructor& reconstructor) {
    (void)report;
    (void)T_world_cam_initial;
    (void)reconstructor;
    return Status::ok();
  }
};

struct FrameOutcome {
  FrameReport report;
  // The first failure of the store's calls: the frame was processed all the same (a full disk
  // must not stop the scan), and the caller reports it.
  Status store_status;
  bool keyframe = false;  // the frame became a keyframe of the pose graph
  // A loop closure applied before this frame: every earlier frame's pose moves with its keyframe
  // (AppliedCorrection::motion_of), the report's pose is already in the corrected frame.
  std::optional<AppliedCorrection> correction;
};

// What the scan file keeps of the pose graph and of how the map follows it, as of a checkpoint.
struct GraphCheckpoint {
  ScanGraphState graph;
  DeformationHistory deformation;
  bool empty() const { return graph.keyframes.empty() && graph.version == 0; }
};

class LoopCloser;

class FramePath {
 public:
  // `store` may be null: nothing is paged or recorded. Loop closure (loop_closure.enabled, frames
  // without hints) runs on a thread of its own with `background_loop_closure` (the fusion daemon:
  // the fusion thread never waits for it), otherwise within run() (offline: repeatable).
  FramePath(IncrementalReconstructor& reconstructor, FrameStore* store = nullptr,
            bool background_loop_closure = false);
  ~FramePath();

  // A failure of process() itself (a frame that cannot be measured) is the error; the store's are
  // in the outcome. With FrameWork::kTrackOnly the frame is tracked and joins the pose graph's
  // odometry, but is not fused, recorded or made a keyframe.
  Result<FrameOutcome> run(const Frame& frame, FrameWork work = FrameWork::kTrackAndFuse);
  // The end of a scan or sequence: waits for the loop closer and applies what it found last.
  std::optional<AppliedCorrection> finish();

  const ScanGraph& graph() const { return graph_; }
  // The graph and the map's deformation as they stand (a checkpoint copies them: the keyframes'
  // clouds are shared).
  GraphCheckpoint checkpoint_state() const;
  // A resumed scan, before its first frame: the graph as its checkpoint had it (the map's
  // deformation is the reconstructor's, restored with the map). The loop closer takes its loop
  // edges and its keyframes, so that a later closure can use keyframes from before the restart
  // and keeps the loops found then. An error changes nothing.
  Status restore(ScanGraphState graph);
  LoopClosureStats loop_closure_stats() const;

 private:
  std::optional<AppliedCorrection> apply_correction();
  void join_graph(const Frame& frame, const FrameReport& report, FrameOutcome* outcome);
  void submit_graph();

  IncrementalReconstructor& reconstructor_;
  FrameStore* store_;
  ScanGraph graph_;
  std::unique_ptr<LoopCloser> closer_;  // null without loop closure
};

}  // namespace depthfuse
