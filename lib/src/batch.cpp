#include "depthfuse/batch.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>

#include "depthfuse/base/log.hpp"
#include "depthfuse/frame_path.hpp"
#include "frame_measure.hpp"

DF_LOG_CATEGORY(Tracking)

namespace depthfuse {

namespace {

using Clock = std::chrono::steady_clock;
inline double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

}  // namespace

SequenceFuser::SequenceFuser(const ReconstructionConfig& config)
    : config_(config.with_method(config.pipeline.method)),
      map_(std::make_unique<PointMap>(config.fusion.chunk_size_m)),
      fuser_(config_.sensor, config_.fusion),
      start_(Clock::now()) {}

SequenceFuser::~SequenceFuser() = default;

Status SequenceFuser::add(const Frame& frame, const Pose& T_world_cam,
                          const CameraVelocity* velocity) {
  const Result<size_t> removed = measure_frame(frame, config_, &scratch_, velocity);
  if (!removed) return removed.status();
  // The pre-filter only marks measurements invalid: those it removed were valid before.
  measurements_ += scratch_.valid_count() + *removed;
  prefiltered_ += *removed;
  ++frames_;
  fuser_.fuse(scratch_, &frame.color, T_world_cam, static_cast<uint32_t>(frames_), map_.get());
  return Status::ok();
}

BatchResult SequenceFuser::finish() {
  BatchResult result;
  result.input_measurements = measurements_;
  result.prefiltered = prefiltered_;
  BatchIterationReport pass;
  pass.points = map_->point_count();
  pass.seconds = ms_since(start_) / 1000;
  result.iterations.push_back(pass);
  if (config_.postfilter.enabled) result.postfiltered = postfilter(map_.get());
  result.map = std::move(map_);
  return result;
}

namespace {

// Fuses every frame with its pose into a fresh map.
Result<std::unique_ptr<PointMap>> fuse_all(const std::vector<Frame>& frames,
                                           const std::vector<Pose>& poses,
                                           const std::vector<CameraVelocity>& velocities,
                                           const ReconstructionConfig& c, size_t* prefiltered,
                                           size_t* measurements, const ProgressFn& progress,
                                           const std::string& stage) {
  SequenceFuser fuser(c);
  for (size_t i = 0; i < frames.size(); ++i) {
    const CameraVelocity* velocity = i < velocities.size() ? &velocities[i] : nullptr;
    DF_RETURN_IF_ERROR(
        fuser.add(frames[i], poses[i], velocity).with_context("frame " + std::to_string(i)));
    if (progress) progress(stage, i + 1, frames.size());
  }
  *prefiltered = fuser.prefiltered();
  *measurements = fuser.measurements();
  return fuser.take_map();
}

// One round of re-registration: every frame against the map from its current pose. The refined
// poses (a frame that does not converge keeps its own), with the round's largest change and mean
// fit in `rep`.
Result<std::vector<Pose>> register_round(const std::vector<Frame>& frames,
                                         const std::vector<Pose>& T_world_cam,
                                         const std::vector<CameraVelocity>& velocities,
                                         const PointMap& map, const ReconstructionConfig& c,
                                         int round, Registrar& registrar, MeasurementImage* m,
                                         const ProgressFn& progress, BatchIterationReport* rep) {
  std::vector<Pose> refined = T_world_cam;
  size_t registered = 0;
  for (size_t i = 0; i < frames.size(); ++i) {
    Result<size_t> r =
        measure_frame(frames[i], c, m, i < velocities.size() ? &velocities[i] : nullptr);
    if (!r) return r.status();
    // The first round starts from the initial poses, which may be several centimetres off:
    // coarse to fine, with wider correspondence gates. Later rounds only refine.
    const RegistrationResult reg = round == 1 ? registrar.track(*m, map, T_world_cam[i])
                                              : registrar.refine(*m, map, T_world_cam[i]);
    if (reg.converged) {
      refined[i] = reg.T_world_cam;
      rep->max_translation_change_m =
          std::max(rep->max_translation_change_m,
                   (reg.T_world_cam.translation() - T_world_cam[i].translation()).norm());
      rep->max_rotation_change_deg = std::max(
          rep->max_rotation_change_deg, rotation_between_deg(reg.T_world_cam, T_world_cam[i]));
      rep->mean_fitness += reg.fitness;
      rep->mean_rmse_m += reg.rmse_m;
      ++registered;
    }
    if (progress) progress("re-registration " + std::to_string(round), i + 1, frames.size());
  }
  rep->registered = registered;
  if (registered) {
    rep->mean_fitness /= registered;
    rep->mean_rmse_m /= registered;
  }
  return refined;
}

}  // namespace

Result<BatchResult> reconstruct_batch(const std::vector<Frame>& frames,
                                      const std::vector<Pose>& T_world_cam_initial,
                                      const ReconstructionConfig& config,
                                      const ProgressFn& progress) {
  if (frames.empty()) return invalid_argument("the sequence has no frames");
  if (frames.size() != T_world_cam_initial.size())
    return invalid_argument("got " + std::to_string(frames.size()) + " frames but " +
                            std::to_string(T_world_cam_initial.size()) + " poses");
  const ReconstructionConfig c = config.with_method(config.pipeline.method);

  BatchResult result;
  result.T_world_cam = T_world_cam_initial;
  MeasurementImage m;  // the re-registration's
  size_t measurements = 0;

  const int rounds = c.registration.enabled ? std::max(0, c.pipeline.outer_iterations) : 0;
  // While the poses are being refined, every measurement stays in the cloud (no redundancy gate):
  // re-registration then aligns each frame with the surface of all frames, not with whichever
  // frame first put points there. The cloud that is returned is fused with the gate once the poses
  // are final.
  ReconstructionConfig c_refine = c;
  if (rounds > 0) c_refine.fusion.redundancy_gate = 0.0;

  // A rolling-shutter camera's frames are each taken over a motion, which the velocities the
  // current poses give undo (docs/architecture.md). For a global shutter none are computed.
  const bool rolling_shutter = std::any_of(frames.begin(), frames.end(), [&](const Frame& f) {
    return row_readout_s(f, c.sensor) > 0.0;
  });
  auto velocities_of = [&](const std::vector<Pose>& poses) {
    return rolling_shutter ? camera_velocities(frames, poses) : std::vector<CameraVelocity>{};
  };
  std::vector<CameraVelocity> velocities = velocities_of(result.T_world_cam);

  auto t0 = Clock::now();
  auto fused = fuse_all(frames, result.T_world_cam, velocities, c_refine, &result.prefiltered,
                        &measurements, progress, "fusion 0");
  if (!fused) return fused.status();
  result.map = std::move(fused.value());
  result.input_measurements = measurements;
  BatchIterationReport first;  // the first fusion: no registration yet
  first.points = result.map->point_count();
  first.seconds = ms_since(t0) / 1000;
  result.iterations.push_back(first);

  Registrar registrar(c.registration);
  for (int round = 1; round <= rounds; ++round) {
    t0 = Clock::now();
    BatchIterationReport rep;
    rep.iteration = round;
    auto refined = register_round(frames, result.T_world_cam, velocities, *result.map, c, round,
                                  registrar, &m, progress, &rep);
    if (!refined) return refined.status();
    result.T_world_cam = std::move(*refined);
    velocities = velocities_of(result.T_world_cam);
    fused = fuse_all(frames, result.T_world_cam, velocities, c_refine, &result.prefiltered,
                     &measurements, progress, "fusion " + std::to_string(round));
    if (!fused) return fused.status();
    result.map = std::move(fused.value());
    rep.points = result.map->point_count();
    rep.seconds = ms_since(t0) / 1000;
    result.iterations.push_back(rep);
    if (rep.max_translation_change_m < c.pipeline.converged_translation_m &&
        rep.max_rotation_change_deg < c.pipeline.converged_rotation_deg) {
      result.converged_early = round < rounds;
      break;
    }
  }
  if (rounds > 0 && c.fusion.redundancy_gate > 0.0) {
    fused = fuse_all(frames, result.T_world_cam, velocities, c, &result.prefiltered, &measurements,
                     progress, "final fusion");
    if (!fused) return fused.status();
    result.map = std::move(fused.value());
  }
  if (c.postfilter.enabled) result.postfiltered = postfilter(result.map.get());
  return result;
}

Result<TrackedSequence> track_sequence(const std::vector<Frame>& frames,
                                       const ReconstructionConfig& config,
                                       const ProgressFn& progress) {
  if (frames.empty()) return invalid_argument("the sequence has no frames");
  ReconstructionConfig c = config.with_method(Method::kFull);
  IncrementalReconstructor rec(c);
  TrackedSequence out;
  out.T_world_cam.reserve(frames.size());
  out.state.reserve(frames.size());
  FramePath path(rec);
  std::vector<uint32_t> frame_ids;  // of the poses in `out`, to move them with a loop closure
  frame_ids.reserve(frames.size());
  auto corrected = [&](const AppliedCorrection& c) {
    for (size_t j = 0; j < out.T_world_cam.size(); ++j)
      if (out.state[j] != TrackingState::kLost)
        out.T_world_cam[j] = c.motion_of(frame_ids[j]) * out.T_world_cam[j];
    ++out.corrections;
  };
  for (size_t i = 0; i < frames.size(); ++i) {
    Frame f = frames[i];
    f.T_world_cam_hint.reset();
    Result<FrameOutcome> outcome = path.run(f);
    if (!outcome) return outcome.status().with_context("frame " + std::to_string(i));
    if (outcome->correction) corrected(*outcome->correction);
    const FrameReport& r = outcome->report;
    // One line a frame (DEPTHFUSE_LOG=Tracking=debug): what decided the frame's state, to be read
    // against a ground truth when a track goes wrong.
    DF_LOG(Tracking, Debug) << "frame " << i << " " << to_string(r.tracking)
                            << (r.tracking_retried ? " retried" : "")
                            << (r.relocalised ? " relocalised" : "")
                            << (r.relocalisations_ambiguous > 0 ? " ambiguous" : "")
                            << (outcome->keyframe ? " keyframe" : "")
                            << " fitness " << r.registration.fitness << " model_fitness "
                            << r.registration.model_fitness << " rmse_mm "
                            << r.registration.rmse_m * 1e3 << " conditioning "
                            << r.registration.conditioning << " data_share "
                            << r.registration.data_share << " reference "
                            << rec.model_fitness_reference() << " t "
                            << r.T_world_cam.translation().transpose();
    out.T_world_cam.push_back(r.T_world_cam);
    out.state.push_back(r.tracking);
    frame_ids.push_back(r.frame_id);
    if (r.tracking == TrackingState::kUncertain) ++out.uncertain;
    if (!r.fused()) ++out.lost;
    if (r.relocalised) ++out.relocalised;
    out.ambiguous += static_cast<size_t>(r.relocalisations_ambiguous);
    if (progress) progress("tracking", i + 1, frames.size());
  }
  if (const std::optional<AppliedCorrection> last = path.finish()) corrected(*last);
  out.keyframes = path.graph().keyframes().size();
  out.loops = path.graph().loops().size();
  return out;
}

}  // namespace depthfuse
