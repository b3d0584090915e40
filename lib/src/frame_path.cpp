#include "depthfuse/frame_path.hpp"

namespace depthfuse {

Result<FrameOutcome> FramePath::run(const Frame& frame) {
  // Without a hint, tracking starts where the camera's last motion puts it, scaled to the frame's
  // time: a start at the last pose is a whole step away, two or three once frames are dropped, and
  // ICP then needs more iterations per frame.
  const std::optional<Pose> prediction =
      frame.T_world_cam_hint ? std::nullopt
                             : reconstructor_.constant_velocity_prediction(frame.utime);
  FrameOutcome outcome;
  if (store_)
    outcome.store_status = store_->prepare_frame(
        frame, reconstructor_.initial_pose(frame, prediction), reconstructor_);
  Result<FrameReport> report = reconstructor_.process(frame, prediction);
  if (!report) return report.status();
  outcome.report = std::move(*report);
  if (store_ && outcome.report.fused()) {
    Status recorded = store_->frame_fused(frame, outcome.report, reconstructor_);
    if (outcome.store_status.is_ok()) outcome.store_status = std::move(recorded);
  }
  return outcome;
}

}  // namespace depthfuse
