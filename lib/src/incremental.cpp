#include "depthfuse/incremental.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>

#include "frame_measure.hpp"
#include "relocaliser.hpp"

namespace depthfuse {

namespace {

using Clock = std::chrono::steady_clock;
inline double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

// Whether a frame whose initial pose is T may be aligned to `last`, the model rendered for the
// frame before, after `reused` frames registered to it in a row (0: none rendered since a reset).
// Without a hint T is the previous refined pose, so the distance says how far the last ICP moved
// the camera rather than how far it moved since; the frame count bounds the reuse either way.
bool may_reuse(const RegistrationConfig& c, int reused, const SurfaceView& last, const Pose& T) {
  return reused > 0 && reused < c.live_model_reuse_frames && !last.empty() &&
         (T.translation() - last.T_world_cam.translation()).norm() <= c.live_model_reuse_max_m &&
         rotation_between_deg(T, last.T_world_cam) <= c.live_model_reuse_max_deg;
}

}  // namespace

IncrementalReconstructor::IncrementalReconstructor(const ReconstructionConfig& config)
    : config_(config.with_method(config.pipeline.method)),
      map_(std::make_unique<PointMap>(config.fusion.chunk_size_m)),
      // A point lies within the sensor's range of its frame's camera, and the camera walks about a
      // metre within a keyframe segment at most.
      deformation_(config.sensor.max_depth_m + 1.0),
      fuser_(config_.sensor, config_.fusion),
      registrar_(config_.registration),
      relocaliser_(std::make_unique<Relocaliser>(config_.relocalisation)),
      motion_error_sq_(initial_motion_error_sq()) {}

IncrementalReconstructor::~IncrementalReconstructor() = default;

size_t IncrementalReconstructor::relocalisation_bytes(const RelocalisationConfig& config,
                                                      size_t pixels) {
  return Relocaliser::memory_bound_bytes(config, pixels);
}

bool IncrementalReconstructor::reachable(const Pose& T_world_cam, int64_t utime) const {
  if (!placed_last_) return true;
  // The last placed frame's own error and ICP's: a tenth of a metre, ten degrees.
  constexpr double kSlackM = 0.1, kSlackDeg = 10.0;
  const double dt_s = std::max<double>(0.0, static_cast<double>(utime - placed_last_->utime) * 1e-6);
  const Pose delta = placed_last_->T_world_cam.inverse() * T_world_cam;
  const double turned_deg = Eigen::AngleAxisd(delta.linear()).angle() * 180.0 / M_PI;
  const RelocalisationConfig& c = config_.relocalisation;
  return delta.translation().norm() <= c.max_speed_m_s * dt_s + kSlackM &&
         turned_deg <= c.max_turn_deg_s * dt_s + kSlackDeg;
}

void IncrementalReconstructor::relocalise(int64_t utime, FrameReport* report) {
  const auto t0 = Clock::now();
  std::optional<RegistrationResult> first;  // the place search returns the first one verified
  bool ambiguous = false;
  const auto found = relocaliser_->search(
      scratch_,
      [&](const Pose& candidate) -> std::optional<Pose> {
        const RegistrationResult r = registrar_.track(scratch_, *map_, candidate);
        frames_since_model_ = 1;  // the track rendered the map around the candidate
        if (!relocalisation_verified(r, config_.registration, model_fitness_reference()))
          return std::nullopt;
        if (!reachable(r.T_world_cam, utime)) {
          ++report->relocalisations_out_of_reach;
          return std::nullopt;
        }
        if (!first) first = r;
        return r.T_world_cam;
      },
      &ambiguous);
  if (ambiguous) ++report->relocalisations_ambiguous;
  if (found) {
    report->registration = *first;
    report->registered = true;
    report->tracking = TrackingState::kTracked;
    report->relocalised = true;
  }
  report->relocalisation_ms = ms_since(t0);
}

Result<FrameReport> IncrementalReconstructor::process(const Frame& frame,
                                                      const std::optional<Pose>& prediction,
                                                      FrameWork work) {
  FrameReport report;
  report.frame_id = next_frame_id_;
  auto t0 = Clock::now();
  Result<size_t> removed = measure(frame);
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

  Pose T = initial_pose(frame, prediction);
  // After a loop closure, the map around the frame follows it before the frame meets the map.
  const auto deform = [&](const auto& step) {
    const auto t = Clock::now();
    step();
    report.deformation_ms += ms_since(t);
  };
  deformation_.set_current_frame(next_frame_id_);
  deform([&] { deformation_.update_visible(map_.get(), scratch_, T); });
  // The model rendered for an earlier frame shows the map before the last correction.
  if (model_version_ != deformation_.version()) {
    model_version_ = deformation_.version();
    frames_since_model_ = 0;
  }
  t0 = Clock::now();
  registrar_.set_frame_color(frame.color, scratch_);
  if (config_.registration.enabled && map_->point_count() > 0)
    register_frame(frame, prediction, &T, &report);
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

  note_tracked(frame, T, report);
  report.fusion_shed = work == FrameWork::kTrackOnly && map_->point_count() > 0;
  if (report.fusion_shed) {
    placed_at(frame.utime, T);
  } else {
    // Registration may have moved the pose far (a relocalisation).
    deform([&] { deformation_.update_visible_if_moved(map_.get(), scratch_, T); });
    t0 = Clock::now();
    report.fusion = fuser_.fuse(scratch_, &frame.color, T, next_frame_id_, map_.get());
    report.fusion_ms = ms_since(t0);
    deform([&] {
      report.swept_points = deformation_.sweep(
          map_.get(), T.translation(),
          static_cast<size_t>(std::max(1, config_.fusion.deform_points_per_frame)));
    });
    fused_at(frame.utime, T);
  }
  registrar_.keep_frame_as_photometric_reference(scratch_, T);
  ++next_frame_id_;
  return report;
}

Result<size_t> IncrementalReconstructor::measure(const Frame& frame) {
  // A rolling shutter (row_readout_s > 0) shears a moving camera's depth map, and a sheared map
  // fits no rigid pose: tracking takes the shear for a shift (the batch loop's figures in
  // docs/history/results-sessions-1-33.md). Frame by frame the motion through this frame is not
  // known yet; the motion through the last two fused frames is the constant-velocity model's guess
  // of it. A hint is a pose from elsewhere, and its frames are
  // taken as they are.
  const std::optional<CameraVelocity> velocity =
      frame.T_world_cam_hint ? std::nullopt : camera_velocity_through_next(frame.utime);
  return measure_frame(frame, config_, &scratch_, velocity ? &*velocity : nullptr);
}

void IncrementalReconstructor::note_tracked(const Frame& frame, const Pose& T_world_cam,
                                            const FrameReport& report) {
  // Only a frame tracked without a hint is a keyframe: with hints, or without registration,
  // nothing is ever relocalised.
  if (!config_.registration.enabled || frame.T_world_cam_hint ||
      report.tracking != TrackingState::kTracked)
    return;
  relocaliser_->frame_tracked(scratch_, T_world_cam, report.frame_id);
  // The first frame, on an empty map, has nothing to agree with.
  if (report.registered)
    recent_model_fitness_[recent_model_fitness_count_++ % recent_model_fitness_.size()] =
        static_cast<float>(report.registration.model_fitness);
}

Pose IncrementalReconstructor::initial_pose(const Frame& frame,
                                            const std::optional<Pose>& prediction) const {
  if (frame.T_world_cam_hint) return *frame.T_world_cam_hint;
  if (prediction) return *prediction;
  return last_T_world_cam_.value_or(Pose::Identity());
}

void IncrementalReconstructor::register_frame(const Frame& frame,
                                              const std::optional<Pose>& prediction,
                                              Pose* T_world_cam, FrameReport* report) {
  const Pose T = *T_world_cam;
  const bool hint = frame.T_world_cam_hint.has_value();
  // Without a hint: the tracking of a moving camera. From a prediction, a MAP estimate with the
  // motion model's prior; without one (the first frames, after a loss), the directions the view
  // does not constrain keep the value of the pose the track starts from, and the track looks
  // further, since nothing has moved its start with the camera.
  const std::optional<MotionPrior> prior =
      hint ? std::nullopt : motion_prior(frame.utime, prediction);
  const std::optional<Pose> held = hint ? std::nullopt : std::optional<Pose>(T);
  auto track = [&](const auto& model, const Pose& start) {
    if (prior) return registrar_.track(scratch_, model, start, *prior);
    if (!prediction) return registrar_.track_without_motion(scratch_, model, start);
    return registrar_.track(scratch_, model, start, held);
  };
  const SurfaceView& last = registrar_.model();
  if (may_reuse(config_.registration, frames_since_model_, last, T)) {
    report->registration = hint ? registrar_.refine(scratch_, last, T) : track(last, T);
    ++frames_since_model_;
    report->model_reused = true;
  } else {
    report->registration = hint ? registrar_.refine(scratch_, *map_, T) : track(*map_, T);
    frames_since_model_ = 1;
  }
  const double reference = model_fitness_reference();
  if (!hint && prediction && last_T_world_cam_ && config_.registration.tracking_retry_fitness > 0 &&
      (report->registration.fitness < config_.registration.tracking_retry_fitness ||
       classify_tracking(report->registration, config_.registration, reference) ==
           TrackingState::kLost))
    retry_from_last_pose(prior ? &*prior : nullptr, report);
  report->registered = report->registration.converged;
  if (!hint)
    report->tracking = classify_tracking(report->registration, config_.registration, reference);
  else if (!report->registered)
    report->tracking = TrackingState::kUncertain;
  if (report->tracking == TrackingState::kLost && !hint) relocalise(frame.utime, report);
  if (report->registered) *T_world_cam = report->registration.T_world_cam;
  if (prior && report->registered && !report->relocalised &&
      report->tracking != TrackingState::kLost)
    learn_motion(*prior, report->registration);
}

// A constant-velocity prediction overshoots where the camera stops or turns back. Of two local
// minima the one with the lower robust cost over all sampled measurements explains more of the
// frame, and better: fitness alone would prefer many loose pairs, the residual alone few tight
// ones. With the motion prior the second start keeps the same prior: only where the track starts
// differs, so that in a direction the view does not constrain both end where the motion model
// puts the camera. (Without it, that direction is held where each starts, and the track would jump
// between the motion model and a standstill.)
void IncrementalReconstructor::retry_from_last_pose(const MotionPrior* prior,
                                                    FrameReport* report) {
  const RegistrationResult second =
      prior ? registrar_.track(scratch_, *map_, *last_T_world_cam_, *prior)
            : registrar_.track(scratch_, *map_, *last_T_world_cam_, *last_T_world_cam_);
  frames_since_model_ = 1;
  if (second.converged &&
      (!report->registration.converged || second.mean_cost < report->registration.mean_cost)) {
    report->registration = second;
    report->model_reused = false;  // the second track rendered the map
  }
  report->tracking_retried = true;
}

std::optional<MotionPrior> IncrementalReconstructor::motion_prior(
    int64_t utime, const std::optional<Pose>& prediction) const {
  const RegistrationConfig& c = config_.registration;
  if (!c.motion_prior || !prediction || !placed_before_last_ || !placed_last_) return std::nullopt;
  const double min_rad = c.motion_prior_min_deg * M_PI / 180.0;
  Vector6d sigma;
  for (int k = 0; k < 6; ++k)
    sigma(k) = std::max(k < 3 ? min_rad : c.motion_prior_min_m, std::sqrt(motion_error_sq_(k)));
  // A hand speeds the camera up along no axis of the camera's own in particular, so the spread
  // learned on one translation axis says what the others may do: each takes the largest measured
  // on any. Learned per axis, an axis the depth measured only on a steady stretch keeps that
  // stretch's small spread, and where the camera then speeds up along it while the depth says
  // little (past a long sofa, with frames dropped), the prior holds the track back a little each
  // step and it falls behind for good. An axis no frame has measured yet keeps its own loose start:
  // it says nothing of the motion model, and a prior pulled wide on its account would let a few
  // pairs at a crease, whose normals straddle it, push the pose along a plain wall.
  double measured_m = 0;
  for (int k = 3; k < 6; ++k)
    if (motion_measured_[k]) measured_m = std::max(measured_m, sigma(k));
  for (int k = 3; k < 6; ++k) sigma(k) = std::max(sigma(k), measured_m);
  // The prediction is the last step stretched to this frame's time: after dropped frames its error
  // grows with the stretch. Not with its square: after a gap of a second the prior would then say
  // nothing of a direction the view does not see (metres), and neither would the odometry edge the
  // pose graph gets, so that any loop's weak pull along that direction would move the keyframe.
  const double period = static_cast<double>(placed_last_->utime - placed_before_last_->utime);
  const double stretch = period > 0 ? static_cast<double>(utime - placed_last_->utime) / period : 1.0;
  sigma *= std::max(1.0, stretch);
  MotionPrior prior;
  prior.T_world_cam = *prediction;
  prior.information = sigma.cwiseAbs2().cwiseInverse().asDiagonal();
  return prior;
}

void IncrementalReconstructor::learn_motion(const MotionPrior& prior, const RegistrationResult& r) {
  // How much of each axis the depth decided: the diagonal of covariance * information (1 - that of
  // the prior). An axis the motion model decided says nothing of the model's error.
  const Matrix6d share = r.covariance * r.information;
  const Vector6d error = pose_delta(prior.T_world_cam, r.T_world_cam);
  constexpr double kMinShare = 0.8;
  constexpr double kWeight = 0.1;  // a running mean over about ten frames
  for (int k = 0; k < 6; ++k) {
    if (share(k, k) < kMinShare) continue;
    motion_measured_[k] = true;
    motion_error_sq_(k) = (1 - kWeight) * motion_error_sq_(k) + kWeight * error(k) * error(k);
  }
}

Vector6d IncrementalReconstructor::initial_motion_error_sq() const {
  const double rad = 5.0 * config_.registration.motion_prior_min_deg * M_PI / 180.0;
  const double m = 5.0 * config_.registration.motion_prior_min_m;
  Vector6d v;
  v << rad * rad, rad * rad, rad * rad, m * m, m * m, m * m;
  return v;
}

bool IncrementalReconstructor::step_spans(const std::optional<StampedPose>& before,
                                          const std::optional<StampedPose>& last, int64_t utime,
                                          int64_t max_gap_us) {
  if (!before || !last) return false;
  const int64_t between_us = last->utime - before->utime;
  return between_us > 0 && between_us <= max_gap_us && utime > last->utime &&
         utime - last->utime <= max_gap_us;
}

std::optional<CameraVelocity> IncrementalReconstructor::camera_velocity_through_next(
    int64_t utime) const {
  // Across a gap (frames lost, dropped by a full queue, or a stride of more than a few frames) the
  // last motion says little about the shear of this frame's readout.
  if (!step_spans(fused_before_last_, fused_last_, utime, 200000)) return std::nullopt;
  return camera_velocity(fused_before_last_->T_world_cam, fused_last_->T_world_cam,
                         static_cast<double>(fused_last_->utime - fused_before_last_->utime) * 1e-6,
                         fused_last_->T_world_cam);
}

std::optional<Pose> IncrementalReconstructor::constant_velocity_prediction(int64_t utime) const {
  // Across a gap of up to a second (frames dropped while the fusion thread waited), the last
  // step still says more about where a hand-held camera went than that it stood still, which is
  // what tracking without a prediction holds in the directions the view does not constrain; the
  // motion prior widens with the gap (motion_prior()). Beyond a second it says little.
  if (!step_spans(placed_before_last_, placed_last_, utime, 1000000)) return std::nullopt;
  const double scale = static_cast<double>(utime - placed_last_->utime) /
                       static_cast<double>(placed_last_->utime - placed_before_last_->utime);
  // The step between the last two, as a rotation about one axis and a translation, stretched to
  // this frame's time: after frames dropped by a full queue the step is two or three of them.
  const Pose step = placed_before_last_->T_world_cam.inverse() * placed_last_->T_world_cam;
  const Eigen::AngleAxisd rotation(step.rotation());
  Pose scaled = Pose::Identity();
  scaled.linear() = Eigen::AngleAxisd(rotation.angle() * scale, rotation.axis()).toRotationMatrix();
  scaled.translation() = step.translation() * scale;
  return placed_last_->T_world_cam * scaled;
}

void IncrementalReconstructor::placed_at(int64_t utime, const Pose& T_world_cam) {
  last_T_world_cam_ = T_world_cam;
  placed_before_last_ = placed_last_;
  placed_last_ = StampedPose{utime, T_world_cam};
}

void IncrementalReconstructor::fused_at(int64_t utime, const Pose& T_world_cam) {
  placed_at(utime, T_world_cam);
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
  Result<size_t> removed = measure(frame);
  if (!removed) return removed.status().with_context("replaying frame " + std::to_string(frame_id));
  // A resumed scan's map may hold chunks that have not followed the corrections before the crash:
  // as in process(), those the frame meets follow them first.
  deformation_.set_current_frame(frame_id);
  deformation_.update_visible(map_.get(), scratch_, T_world_cam);
  fuser_.fuse(scratch_, &frame.color, T_world_cam, frame_id, map_.get());
  fused_at(frame.utime, T_world_cam);
  // The registrar's model and photometric reference are of frames before the crash, or none.
  frames_since_model_ = 0;
  registrar_.keep_frame_as_photometric_reference(scratch_, T_world_cam);
  next_frame_id_ = frame_id + 1;
  return Status::ok();
}

void IncrementalReconstructor::apply_correction(const AppliedCorrection& c) {
  if (c.motion.empty()) return;
  // The last frames fused belong to the last keyframe: moved together, their step (the motion
  // model's velocity) is the same in the corrected frame.
  const Pose& motion = c.motion.back();
  if (last_T_world_cam_) last_T_world_cam_ = motion * *last_T_world_cam_;
  for (std::optional<StampedPose>* p :
       {&placed_last_, &placed_before_last_, &fused_last_, &fused_before_last_})
    if (*p) (*p)->T_world_cam = motion * (*p)->T_world_cam;
  relocaliser_->move_keyframes(
      [&](uint32_t frame_id, const Pose& T) { return c.motion_of(frame_id) * T; });
  // The last rendered model and the photometric reference are of the map as it was.
  frames_since_model_ = 0;
  registrar_.forget_photometric_reference();
}

size_t IncrementalReconstructor::finish() {
  bring_all_up_to_date();
  return config_.postfilter.enabled ? postfilter(map_.get()) : 0;
}

void IncrementalReconstructor::reset(std::unique_ptr<PointMap> map, uint32_t next_frame_id,
                                     const std::optional<Pose>& last_T_world_cam) {
  map_ = map ? std::move(map) : std::make_unique<PointMap>(config_.fusion.chunk_size_m);
  deformation_.clear();
  model_version_ = 0;
  frames_since_model_ = 0;
  relocaliser_->clear();
  recent_model_fitness_count_ = 0;
  motion_error_sq_ = initial_motion_error_sq();
  motion_measured_ = {};
  next_frame_id_ = std::max<uint32_t>(1, next_frame_id);
  last_T_world_cam_ = last_T_world_cam;
  placed_before_last_.reset();
  placed_last_.reset();
  fused_before_last_.reset();
  fused_last_.reset();
  registrar_.forget_photometric_reference();
}

bool IncrementalReconstructor::keeps_keyframes() const {
  // As in note_tracked(): only frames tracked without a hint become keyframes, so without registration
  // there are none.
  return config_.registration.enabled && config_.relocalisation.enabled;
}

bool IncrementalReconstructor::keyframe_wanted(const Pose& T_world_cam) const {
  return keeps_keyframes() && relocaliser_->wants(T_world_cam);
}

Result<bool> IncrementalReconstructor::restore_keyframe(const Frame& frame, const Pose& T_world_cam,
                                                       uint32_t frame_id) {
  if (!keyframe_wanted(T_world_cam)) return false;
  // The same measurement a live frame gets: the keyframe's thumbnail and points are what they
  // would have been had this process tracked the frame. scratch_ is the next frame's anyway.
  Result<size_t> removed = measure_frame(frame, config_, &scratch_);
  if (!removed) return removed.status();
  return relocaliser_->add_older_keyframe(scratch_, T_world_cam, frame_id);
}

size_t IncrementalReconstructor::keyframe_count() const { return relocaliser_->keyframe_count(); }

}  // namespace depthfuse
