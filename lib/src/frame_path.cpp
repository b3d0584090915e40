#include "depthfuse/frame_path.hpp"

#include "depthfuse/base/log.hpp"
#include "loop_closure.hpp"

namespace depthfuse {

DF_LOG_CATEGORY(Graph)

FramePath::FramePath(IncrementalReconstructor& reconstructor, FrameStore* store,
                     bool background_loop_closure)
    : reconstructor_(reconstructor), store_(store), graph_(reconstructor.config().loop_closure) {
  const ReconstructionConfig& c = reconstructor.config();
  if (c.loop_closure.enabled && c.registration.enabled)
    closer_ = std::make_unique<LoopCloser>(c.loop_closure, c.relocalisation, background_loop_closure);
}

FramePath::~FramePath() = default;

Result<FrameOutcome> FramePath::run(const Frame& frame, FrameWork work) {
  FrameOutcome outcome;
  outcome.correction = apply_correction();
  // Without a hint, tracking starts where the camera's last motion puts it, scaled to the frame's
  // time: a start at the last pose is a whole step away, two or three once frames are dropped, and
  // ICP then needs more iterations per frame.
  const std::optional<Pose> prediction =
      frame.T_world_cam_hint ? std::nullopt
                             : reconstructor_.constant_velocity_prediction(frame.utime);
  const Pose T_world_cam_initial = reconstructor_.initial_pose(frame, prediction);
  if (store_) outcome.store_status = store_->prepare_frame(frame, T_world_cam_initial, reconstructor_);
  Result<FrameReport> report = reconstructor_.process(frame, prediction, work);
  if (!report) return report.status();
  outcome.report = std::move(*report);
  outcome.report.graph_memory_bytes =
      graph_.memory_bytes() + reconstructor_.deformation().memory_bytes();
  if (store_) {
    Status recorded =
        outcome.report.fused()
            ? store_->frame_fused(frame, outcome.report, reconstructor_)
            : store_->frame_not_fused(outcome.report, T_world_cam_initial, reconstructor_);
    if (outcome.store_status.is_ok()) outcome.store_status = std::move(recorded);
  }
  join_graph(frame, outcome.report, &outcome);
  return outcome;
}

void FramePath::join_graph(const Frame& frame, const FrameReport& report, FrameOutcome* outcome) {
  if (!closer_ || frame.T_world_cam_hint || !report.placed()) return;
  // The first frame is placed by definition; a relocalised one was found by a search, not tracked
  // from the last: nothing is known of how it moved since.
  Matrix6d covariance = Matrix6d::Zero();
  if (report.relocalised)
    covariance = Matrix6d::Identity();
  else if (report.registered)
    covariance = report.registration.covariance;
  if (!report.fused()) {
    graph_.frame_tracked(report.T_world_cam, covariance);
    return;
  }
  if (!graph_.frame_fused(report.frame_id, frame.utime, report.T_world_cam, covariance,
                          reconstructor_.measurement()))
    return;
  outcome->keyframe = true;
  const std::vector<GraphKeyframe>& keyframes = graph_.keyframes();
  const Status added = reconstructor_.deformation().keyframe_added(
      static_cast<uint32_t>(keyframes.size() - 1), keyframes.back().frame_id,
      keyframes.back().T_world_kf);
  if (!added) DF_LOG(Graph, Error) << "the map cannot follow keyframe " << keyframes.size() - 1
                                   << ": " << added.message();
  submit_graph();
  graph_.forget_redundant_clouds(closer_->searched());
}

void FramePath::submit_graph() {
  GraphSnapshot snapshot;
  snapshot.keyframes = graph_.keyframes();
  snapshot.odometry = graph_.odometry();
  snapshot.odometry_covariance = graph_.odometry_covariance();
  closer_->submit(std::move(snapshot));
}

GraphCheckpoint FramePath::checkpoint_state() const {
  return GraphCheckpoint{graph_.state(), reconstructor_.deformation().history()};
}

Status FramePath::restore(ScanGraphState graph) {
  DF_RETURN_IF_ERROR(graph_.restore(std::move(graph)));
  if (closer_ && !graph_.keyframes().empty()) {
    closer_->restore(graph_.loops(), graph_.keyframes().size());
    submit_graph();
  }
  return Status::ok();
}

std::optional<AppliedCorrection> FramePath::apply_correction() {
  if (!closer_) return std::nullopt;
  std::optional<GraphCorrection> c = closer_->take();
  if (!c) return std::nullopt;
  AppliedCorrection applied = graph_.apply(*c);
  reconstructor_.apply_correction(applied);
  // The map follows the keyframes where the graph now has them, chunk by chunk from the next frame
  // on (MapDeformation).
  std::vector<Pose> T_world_kf;
  T_world_kf.reserve(graph_.keyframes().size());
  for (const GraphKeyframe& k : graph_.keyframes()) T_world_kf.push_back(k.T_world_kf);
  const Result<uint32_t> version = reconstructor_.deformation().correct(T_world_kf);
  if (!version) DF_LOG(Graph, Error) << "the map cannot follow the correction: " << version.status().message();
  return applied;
}

std::optional<AppliedCorrection> FramePath::finish() {
  if (!closer_) return std::nullopt;
  closer_->wait_idle();
  return apply_correction();
}

LoopClosureStats FramePath::loop_closure_stats() const {
  return closer_ ? closer_->stats() : LoopClosureStats{};
}

}  // namespace depthfuse
