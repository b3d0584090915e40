#include "depthfuse/pipeline.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>

#include "depthfuse/base/log.hpp"
#include "relocaliser.hpp"

DF_LOG_CATEGORY(Tracking)

namespace depthfuse {

namespace {

using Clock = std::chrono::steady_clock;
inline double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

// The per-frame path before registration and fusion, the same for a live frame and for every pass
// of the batch loop: back-projection, normals and (if the method has it) the pre-filter. Returns
// how many measurements the pre-filter removed.
// `velocity`, where the pose sequence gives it, undoes a rolling shutter first (the batch loop:
// frame by frame, the camera's motion through a frame is not known when it is fused).
Result<size_t> measure(const Frame& frame, const ReconstructionConfig& c, MeasurementImage* m,
                       const CameraVelocity* velocity = nullptr) {
  const double readout_s = row_readout_s(frame, c.sensor);
  if (velocity && readout_s > 0.0) {
    Frame at_mid_row;
    at_mid_row.utime = frame.utime;
    at_mid_row.intrinsics = frame.intrinsics;
    if (undo_rolling_shutter(frame, *velocity, readout_s, &at_mid_row.depth)) {
      at_mid_row.color = frame.color;
      DF_RETURN_IF_ERROR(backproject(at_mid_row, c.sensor, c.fusion, m));
      return prefilter(c.prefilter, m, c.fusion.threads);
    }
  }
  DF_RETURN_IF_ERROR(backproject(frame, c.sensor, c.fusion, m));
  return prefilter(c.prefilter, m, c.fusion.threads);
}

// Why a frame has no valid depth measurement: no depth at all, or none inside the sensor's range.
Status no_measurement(const DepthImage& depth, const SensorModelConfig& sensor) {
  size_t zero = 0;
  for (float z : depth.depth_m) zero += !(z > 0.0f);
  const size_t n = depth.depth_m.size();
  char range[64];
  std::snprintf(range, sizeof(range), "[%g, %g] m", sensor.min_depth_m, sensor.max_depth_m);
  std::string why = std::to_string(n) + " pixels, ";
  if (zero == n)
    why += "all 0 (no measurement)";
  else
    why += std::to_string(zero) + " without a measurement and the other " + std::to_string(n - zero) +
           " outside the sensor's range " + range + " (a wrong depth scale?)";
  return invalid_argument("no valid depth measurement: " + why);
}

double rotation_deg(const Pose& a, const Pose& b) {
  const Eigen::AngleAxisd d(a.linear().transpose() * b.linear());
  return std::abs(d.angle()) * 180.0 / M_PI;
}

// Whether a frame whose initial pose is T may be aligned to `last`, the model rendered for the
// frame before, after `reused` frames registered to it in a row (0: none rendered since a reset).
// Without a hint T is the previous refined pose, so the distance says how far the last ICP moved
// the camera rather than how far it moved since; the frame count bounds the reuse either way.
bool may_reuse(const RegistrationConfig& c, int reused, const SurfaceView& last, const Pose& T) {
  return reused > 0 && reused < c.live_model_reuse_frames && !last.empty() &&
         (T.translation() - last.T_world_cam.translation()).norm() <= c.live_model_reuse_max_m &&
         rotation_deg(T, last.T_world_cam) <= c.live_model_reuse_max_deg;
}

}  // namespace

IncrementalReconstructor::IncrementalReconstructor(const ReconstructionConfig& config)
    : config_(config.with_method(config.pipeline.method)),
      map_(std::make_unique<PointMap>(config.fusion.chunk_size_m)),
      fuser_(config_.sensor, config_.fusion),
      registrar_(config_.registration),
      relocaliser_(std::make_unique<Relocaliser>(config_.relocalisation)) {}

IncrementalReconstructor::~IncrementalReconstructor() = default;

size_t IncrementalReconstructor::relocalisation_bytes(const RelocalisationConfig& config,
                                                      size_t pixels) {
  return Relocaliser::memory_bound_bytes(config, pixels);
}

void IncrementalReconstructor::relocalise(FrameReport* report) {
  const auto t0 = Clock::now();
  const auto found = relocaliser_->search(scratch_, [&](const Pose& candidate) {
    const RegistrationResult r = registrar_.track(scratch_, *map_, candidate);
    frames_since_model_ = 1;  // the track rendered the map around the candidate
    if (!relocalisation_verified(r, config_.registration, model_fitness_reference())) return false;
    report->registration = r;
    return true;
  });
  if (found) {
    report->registered = true;
    report->tracking = TrackingState::kTracked;
    report->relocalised = true;
  }
  report->relocalisation_ms = ms_since(t0);
}

Result<FrameReport> IncrementalReconstructor::process(const Frame& frame,
                                                      const std::optional<Pose>& prediction) {
  FrameReport report;
  report.frame_id = next_frame_id_;
  auto t0 = Clock::now();
  // A rolling shutter (row_readout_s > 0) shears a moving camera's depth map, and a sheared map
  // fits no rigid pose: tracking takes the shear for a shift (the batch loop's figures in
  // docs/history/results-sessions-1-33.md). Frame by frame the motion through this frame is not
  // known yet; the motion through the last two fused frames is the constant-velocity model's guess
  // of it. A hint is a pose from elsewhere, and its frames are taken as they are.
  const std::optional<CameraVelocity> velocity =
      frame.T_world_cam_hint ? std::nullopt : camera_velocity_through_next(frame.utime);
  Result<size_t> removed = measure(frame, config_, &scratch_, velocity ? &*velocity : nullptr);
  if (!removed) return removed.status();
  // Nothing to track or fuse: the frame cannot be placed, and tracking from an empty first frame
  // would anchor the map nowhere. Said with the reason, so that a broken sensor or a wrong depth
  // scale is recognised.
  // Once the map has begun, such a frame (the sensor covered for a moment, a dropout) is a gap:
  // lost, nothing fused, and the next frame starts from the last frame fused.
  if (scratch_.valid_count() + *removed == 0) {
    if (map_->point_count() == 0) return no_measurement(frame.depth, config_.sensor);
    report.tracking = TrackingState::kLost;
    report.T_world_cam = last_T_world_cam_.value_or(Pose::Identity());
    frames_since_model_ = 0;
    ++next_frame_id_;
    return report;
  }
  report.prefiltered = *removed;
  report.prefilter_ms = ms_since(t0);

  Pose T = Pose::Identity();
  if (frame.T_world_cam_hint) T = *frame.T_world_cam_hint;
  else if (prediction) T = *prediction;
  else if (last_T_world_cam_) T = *last_T_world_cam_;

  t0 = Clock::now();
  registrar_.set_frame_color(frame.color, scratch_);
  if (config_.registration.enabled && map_->point_count() > 0) {
    const bool hint = frame.T_world_cam_hint.has_value();
    // Without a hint: the tracking of a moving camera. The directions the view does not constrain
    // keep the value the motion model gives them, that of the pose the track starts from.
    const std::optional<Pose> held = hint ? std::nullopt : std::optional<Pose>(T);
    const SurfaceView& last = registrar_.model();
    if (may_reuse(config_.registration, frames_since_model_, last, T)) {
      report.registration = hint ? registrar_.refine(scratch_, last, T)
                                 : registrar_.track(scratch_, last, T, held);
      ++frames_since_model_;
      report.model_reused = true;
    } else {
      report.registration = hint ? registrar_.refine(scratch_, *map_, T)
                                 : registrar_.track(scratch_, *map_, T, held);
      frames_since_model_ = 1;
    }
    // A constant-velocity prediction overshoots where the camera stops or turns back; a poor
    // track from it (lost, or few pairs) gets a second start at the last refined pose. Of two
    // local minima the one with the lower robust cost over all sampled measurements explains more
    // of the frame, and better: fitness alone would prefer many loose pairs, the residual alone
    // few tight ones. A direction held for want of information is no reason to start again: the
    // two starts would differ only there, where the cost cannot tell them apart, and the track
    // would jump between the motion model and a standstill.
    const double reference = model_fitness_reference();
    if (!hint && prediction && last_T_world_cam_ && config_.registration.tracking_retry_fitness > 0 &&
        (report.registration.fitness < config_.registration.tracking_retry_fitness ||
         classify_tracking(report.registration, config_.registration, reference) ==
             TrackingState::kLost)) {
      const RegistrationResult second =
          registrar_.track(scratch_, *map_, *last_T_world_cam_, *last_T_world_cam_);
      frames_since_model_ = 1;
      if (second.converged && (!report.registration.converged ||
                               second.mean_cost < report.registration.mean_cost)) {
        report.registration = second;
        report.model_reused = false;  // the second track rendered the map
      }
      report.tracking_retried = true;
    }
    report.registered = report.registration.converged;
    if (!hint) report.tracking = classify_tracking(report.registration, config_.registration, reference);
    else if (!report.registered) report.tracking = TrackingState::kUncertain;
    if (report.tracking == TrackingState::kLost && !hint) relocalise(&report);
    if (report.registered) T = report.registration.T_world_cam;
  }
  report.registration_ms = ms_since(t0);
  report.T_world_cam = T;
  if (report.tracking == TrackingState::kLost) {
    // The pose is unknown: fusing the frame would put a copy of the scene in the wrong place, and
    // the next frame starts from the last frame fused. The model rendered for this frame covers
    // what it saw from the wrong place: the next frame renders its own.
    frames_since_model_ = 0;
    ++next_frame_id_;
    return report;
  }

  // Only a frame tracked without a hint is a keyframe: with hints, or without registration,
  // nothing is ever relocalised.
  if (config_.registration.enabled && !frame.T_world_cam_hint &&
      report.tracking == TrackingState::kTracked) {
    relocaliser_->frame_tracked(scratch_, T);
    // The first frame, on an empty map, has nothing to agree with.
    if (report.registered)
      recent_model_fitness_[recent_model_fitness_count_++ % recent_model_fitness_.size()] =
          static_cast<float>(report.registration.model_fitness);
  }

  t0 = Clock::now();
  report.fusion = fuser_.fuse(scratch_, &frame.color, T, next_frame_id_, map_.get());
  report.fusion_ms = ms_since(t0);
  fused_at(frame.utime, T);
  registrar_.keep_frame_as_photometric_reference(scratch_, T);
  ++next_frame_id_;
  return report;
}

std::optional<CameraVelocity> IncrementalReconstructor::camera_velocity_through_next(
    int64_t utime) const {
  if (!fused_before_last_ || !fused_last_) return std::nullopt;
  // Across a gap (frames lost, dropped by a full queue, or a stride of more than a few frames) the
  // last motion says little about this frame's.
  constexpr int64_t kMaxGapUs = 200000;
  const int64_t between_us = fused_last_->utime - fused_before_last_->utime;
  if (between_us <= 0 || between_us > kMaxGapUs || utime <= fused_last_->utime ||
      utime - fused_last_->utime > kMaxGapUs)
    return std::nullopt;
  return camera_velocity(fused_before_last_->T_world_cam, fused_last_->T_world_cam,
                         static_cast<double>(between_us) * 1e-6, fused_last_->T_world_cam);
}

std::optional<Pose> IncrementalReconstructor::constant_velocity_prediction(int64_t utime) const {
  if (!camera_velocity_through_next(utime)) return std::nullopt;  // the gap rule
  const double scale = static_cast<double>(utime - fused_last_->utime) /
                       static_cast<double>(fused_last_->utime - fused_before_last_->utime);
  // The step between the last two, as a rotation about one axis and a translation, stretched to
  // this frame's time: after frames dropped by a full queue the step is two or three of them.
  const Pose step = fused_before_last_->T_world_cam.inverse() * fused_last_->T_world_cam;
  const Eigen::AngleAxisd rotation(step.rotation());
  Pose scaled = Pose::Identity();
  scaled.linear() = Eigen::AngleAxisd(rotation.angle() * scale, rotation.axis()).toRotationMatrix();
  scaled.translation() = step.translation() * scale;
  return fused_last_->T_world_cam * scaled;
}

void IncrementalReconstructor::fused_at(int64_t utime, const Pose& T_world_cam) {
  last_T_world_cam_ = T_world_cam;
  fused_before_last_ = fused_last_;
  fused_last_ = StampedPose{utime, T_world_cam};
}

double IncrementalReconstructor::model_fitness_reference() const {
  const size_t n = std::min(recent_model_fitness_count_, recent_model_fitness_.size());
  if (n == 0) return 1.0;
  double sum = 0;
  for (size_t k = 0; k < n; ++k) sum += recent_model_fitness_[k];
  return sum / n;
}

Status IncrementalReconstructor::replay(const Frame& frame, uint32_t frame_id,
                                       const Pose& T_world_cam) {
  if (frame_id == 0 || frame_id == 0xFFFFFFFFu)
    return invalid_argument("replay: frame id " + std::to_string(frame_id) + " is out of range");
  // As process() measured it: replayed in order at the same poses, the same velocity.
  const std::optional<CameraVelocity> velocity =
      frame.T_world_cam_hint ? std::nullopt : camera_velocity_through_next(frame.utime);
  Result<size_t> removed = measure(frame, config_, &scratch_, velocity ? &*velocity : nullptr);
  if (!removed) return removed.status().with_context("replaying frame " + std::to_string(frame_id));
  fuser_.fuse(scratch_, &frame.color, T_world_cam, frame_id, map_.get());
  fused_at(frame.utime, T_world_cam);
  // The registrar's model and photometric reference are of frames before the crash, or none.
  frames_since_model_ = 0;
  registrar_.keep_frame_as_photometric_reference(scratch_, T_world_cam);
  next_frame_id_ = frame_id + 1;
  return Status::ok();
}

size_t IncrementalReconstructor::finish() {
  return config_.postfilter.enabled ? postfilter(map_.get()) : 0;
}

void IncrementalReconstructor::reset(std::unique_ptr<PointMap> map, uint32_t next_frame_id,
                                     const std::optional<Pose>& last_T_world_cam) {
  map_ = map ? std::move(map) : std::make_unique<PointMap>(config_.fusion.chunk_size_m);
  frames_since_model_ = 0;
  relocaliser_->clear();
  recent_model_fitness_count_ = 0;
  next_frame_id_ = std::max<uint32_t>(1, next_frame_id);
  last_T_world_cam_ = last_T_world_cam;
  fused_before_last_.reset();
  fused_last_.reset();
  registrar_.forget_photometric_reference();
}

bool IncrementalReconstructor::keeps_keyframes() const {
  // As in process(): only frames tracked without a hint become keyframes, so without registration
  // there are none.
  return config_.registration.enabled && config_.relocalisation.enabled;
}

bool IncrementalReconstructor::keyframe_wanted(const Pose& T_world_cam) const {
  return keeps_keyframes() && relocaliser_->wants(T_world_cam);
}

Result<bool> IncrementalReconstructor::restore_keyframe(const Frame& frame, const Pose& T_world_cam) {
  if (!keyframe_wanted(T_world_cam)) return false;
  // The same measurement a live frame gets: the keyframe's thumbnail and points are what they
  // would have been had this process tracked the frame. scratch_ is the next frame's anyway.
  Result<size_t> removed = measure(frame, config_, &scratch_);
  if (!removed) return removed.status();
  return relocaliser_->add_older_keyframe(scratch_, T_world_cam);
}

size_t IncrementalReconstructor::keyframe_count() const { return relocaliser_->keyframe_count(); }

SequenceFuser::SequenceFuser(const ReconstructionConfig& config)
    : config_(config.with_method(config.pipeline.method)),
      map_(std::make_unique<PointMap>(config.fusion.chunk_size_m)),
      fuser_(config_.sensor, config_.fusion),
      start_(Clock::now()) {}

SequenceFuser::~SequenceFuser() = default;

Status SequenceFuser::add(const Frame& frame, const Pose& T_world_cam,
                          const CameraVelocity* velocity) {
  const Result<size_t> removed = measure(frame, config_, &scratch_, velocity);
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
    std::vector<Pose> refined = result.T_world_cam;
    size_t registered = 0;
    for (size_t i = 0; i < frames.size(); ++i) {
      Result<size_t> r =
          measure(frames[i], c, &m, i < velocities.size() ? &velocities[i] : nullptr);
      if (!r) return r.status();
      // The first round starts from the initial poses, which may be several centimetres off:
      // coarse to fine, with wider correspondence gates. Later rounds only refine.
      const RegistrationResult reg = round == 1
                                         ? registrar.track(m, *result.map, result.T_world_cam[i])
                                         : registrar.refine(m, *result.map, result.T_world_cam[i]);
      if (reg.converged) {
        refined[i] = reg.T_world_cam;
        rep.max_translation_change_m =
            std::max(rep.max_translation_change_m,
                     (reg.T_world_cam.translation() - result.T_world_cam[i].translation()).norm());
        rep.max_rotation_change_deg = std::max(
            rep.max_rotation_change_deg, rotation_deg(reg.T_world_cam, result.T_world_cam[i]));
        rep.mean_fitness += reg.fitness;
        rep.mean_rmse_m += reg.rmse_m;
        ++registered;
      }
      if (progress) progress("re-registration " + std::to_string(round), i + 1, frames.size());
    }
    rep.registered = registered;
    if (registered) {
      rep.mean_fitness /= registered;
      rep.mean_rmse_m /= registered;
    }
    result.T_world_cam = refined;
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
  for (size_t i = 0; i < frames.size(); ++i) {
    Frame f = frames[i];
    f.T_world_cam_hint.reset();
    // Constant velocity from the last two frames if both were fused; after a loss, the last frame
    // fused (IncrementalReconstructor's own start).
    std::optional<Pose> prediction;
    if (i >= 2 && out.state[i - 1] != TrackingState::kLost &&
        out.state[i - 2] != TrackingState::kLost) {
      const Pose& before = out.T_world_cam[i - 2];
      const Pose& last = out.T_world_cam[i - 1];
      prediction = last * (before.inverse() * last);
    }
    Result<FrameReport> r = rec.process(f, prediction);
    if (!r) return r.status().with_context("frame " + std::to_string(i));
    // One line a frame (DEPTHFUSE_LOG=Tracking=debug): what decided the frame's state, to be read
    // against a ground truth when a track goes wrong.
    DF_LOG(Tracking, Debug) << "frame " << i << " " << to_string(r->tracking)
                            << (r->tracking_retried ? " retried" : "")
                            << (r->relocalised ? " relocalised" : "")
                            << " fitness " << r->registration.fitness << " model_fitness "
                            << r->registration.model_fitness << " rmse_mm "
                            << r->registration.rmse_m * 1e3 << " conditioning "
                            << r->registration.conditioning << " reference "
                            << rec.model_fitness_reference() << " t "
                            << r->T_world_cam.translation().transpose();
    out.T_world_cam.push_back(r->T_world_cam);
    out.state.push_back(r->tracking);
    if (r->tracking == TrackingState::kUncertain) ++out.uncertain;
    if (!r->fused()) ++out.lost;
    if (r->relocalised) ++out.relocalised;
    if (progress) progress("tracking", i + 1, frames.size());
  }
  return out;
}

}  // namespace depthfuse
