// The paper's method one frame at a time into a growing map: IncrementalReconstructor (the fusion
// daemon's, and the tracking of the offline tools through FramePath, frame_path.hpp).
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <optional>

#include "depthfuse/config.hpp"
#include "depthfuse/fusion.hpp"
#include "depthfuse/map_deformation.hpp"
#include "depthfuse/measurement.hpp"
#include "depthfuse/point_map.hpp"
#include "depthfuse/registration.hpp"
#include "depthfuse/scan_graph.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse {

struct FrameReport {
  uint32_t frame_id = 0;
  Pose T_world_cam = Pose::Identity();   // the pose the frame was fused with
  bool registered = false;               // ICP ran and converged
  bool model_reused = false;             // ICP aligned to the previous frame's model (no render)
  bool tracking_retried = false;         // a poor track from the prediction started again
  // Tracking was lost and the camera was found among the keyframes (the frame is kTracked and
  // fused at the pose found).
  bool relocalised = false;
  // Places the search found and ICP verified that the camera cannot have got to since the last
  // frame fused (RelocalisationConfig::max_speed_m_s): refused.
  int relocalisations_out_of_reach = 0;
  // A place found that another keyframe's place fits as well (RelocalisationConfig::ambiguity_m):
  // refused, the frame stays lost.
  int relocalisations_ambiguous = 0;
  // Without a pose hint, how far the tracked pose can be trusted (classify_tracking()); with one,
  // tracked if its ICP converged, else uncertain (the hint is fused). A lost frame is not fused.
  TrackingState tracking = TrackingState::kTracked;
  // The frame was tracked but, at the caller's request (FrameWork::kTrackOnly: a live queue falling
  // behind), not fused: it has a pose and the motion model follows it; the map is as it was.
  bool fusion_shed = false;
  // Whether the frame has a pose: it was not lost.
  bool placed() const { return tracking != TrackingState::kLost; }
  // Whether the frame went into the map: placed, and not shed.
  bool fused() const { return placed() && !fusion_shed; }
  RegistrationResult registration;
  FusionStats fusion;
  size_t prefiltered = 0;                // measurements the pre-filter removed
  double prefilter_ms = 0, registration_ms = 0, fusion_ms = 0;
  double relocalisation_ms = 0;          // the keyframe search, part of registration_ms
  // Bringing chunks up to date after a loop closure (MapDeformation): those the frame sees, before
  // registration and before fusion, and the sweep after it, which went over swept_points points
  // (fusion.deform_points_per_frame and at most a chunk more).
  double deformation_ms = 0;
  size_t swept_points = 0;
  // What the scan's pose graph and the map's deformation hold (FramePath fills it in): memory that
  // grows with the scan's length, which the map's budget counts beside its chunks.
  size_t graph_memory_bytes = 0;
};

// What process() does with a frame. A live stream whose frames come faster than fusion takes them
// sheds fusion rather than whole frames: tracking a frame costs a fraction of fusing it, and a
// camera tracked through every frame keeps the short steps its motion model and ICP need (a frame
// dropped doubles the next step). The map loses little: a frame shed sees what its neighbours saw.
enum class FrameWork {
  kTrackAndFuse,
  kTrackOnly,  // registered as usual, not fused; the first frame of a map is fused regardless
};

class Relocaliser;

class IncrementalReconstructor {
 public:
  // What process() holds for a frame besides the map, per pixel of the frame: the measurement
  // image, the rendered model, the model projections of ICP and fusion (two threads) and their
  // scratch, and with colour the photometric term's intensity pyramids. Most of it is kept from
  // frame to frame (the buffers are reused), so it is resident, not a peak. A bound for budgets,
  // held from both sides by a test that counts malloc's mapped blocks too
  // (Incremental.FrameWorkStaysWithinItsBound; the figure is in
  // docs/history/results-sessions-1-33.md).
  static constexpr size_t kWorkBytesPerPixel = 288;

  // What the relocaliser holds at most, keyframes and the search of one frame of `pixels`.
  static size_t relocalisation_bytes(const RelocalisationConfig& config, size_t pixels);

  explicit IncrementalReconstructor(const ReconstructionConfig& config);
  ~IncrementalReconstructor();

  // Pre-filter; initial pose (initial_pose()); re-registration against the map (if the method has
  // it and the map is not empty); fusion. With a hint, ICP refines it; without one, coarse-to-fine tracking runs.
  // The model is the map rendered at the initial pose, for every frame or, with
  // registration.live_model_reuse_frames = n, for every n-th (the first after a reset renders).
  // Without a hint, directions of the pose the view hardly constrains keep the initial pose's
  // value (Registrar::track): the motion model's. A track from a prediction that is lost or has a
  // fitness below registration.tracking_retry_fitness starts again from the last refined pose,
  // and the start whose ICP ends with the lower mean cost is kept. A frame whose track is lost is
  // searched for among the keyframes (Relocaliser; every frame tracked without a hint may become
  // one): a candidate pose that tracks against the map as kTracked, with a model fitness as good as
  // the lost rule asks of a poor track (relocalisation_verified()), is the camera's, and the frame
  // is fused there (relocalised). Otherwise the frame is not fused, and the last refined pose
  // stays that of the last frame placed. With FrameWork::kTrackOnly a placed frame is not fused
  // (FrameReport::fusion_shed), and nothing after registration runs but the motion model's update.
  Result<FrameReport> process(const Frame& frame,
                              const std::optional<Pose>& T_world_cam_prediction = std::nullopt,
                              FrameWork work = FrameWork::kTrackAndFuse);
  // Where a frame's registration starts: its hint if it has one, otherwise `prediction` (the
  // motion model's), otherwise the last refined pose (the origin before any frame). The one rule:
  // process() starts there, and a map pager loads the chunks around it before process() runs.
  Pose initial_pose(const Frame& frame, const std::optional<Pose>& prediction) const;
  // For a live stream, whose frames carry the sensor's times and may be dropped on the way: the
  // pose at `utime` if the camera kept the motion of the last two frames placed, that motion scaled
  // to the time since the last. None before two frames, or across a gap of more than a few frame
  // periods (the same rule as the rolling-shutter velocity's).
  std::optional<Pose> constant_velocity_prediction(int64_t utime) const;

  // Fuses `frame` at `T_world_cam` as frame `frame_id`, with no registration: a frame that was
  // fused before (a scan's frame redo log after a crash). Fusion is the same as process()'s, so
  // the map becomes what it was; frame ids continue after frame_id, the last pose is T_world_cam,
  // and the next frame renders its own model.
  Status replay(const Frame& frame, uint32_t frame_id, const Pose& T_world_cam);

  // A loop closure moved the keyframes: the camera's last poses (and so the motion model's
  // prediction, in the corrected frame), the relocaliser's keyframes and the map move with them,
  // and the next frame renders its model anew.
  void apply_correction(const AppliedCorrection& correction);
  // The last frame's measurements (back-projected, normals, pre-filtered): a keyframe's points.
  const MeasurementImage& measurement() const { return scratch_; }

  // Post-filter the whole map (end of scan), after bringing it up to date.
  size_t finish();

  // How the map follows the pose graph: keyframes are added to it and loop closures correct it
  // (MapDeformation). process() brings the chunks a frame sees up to date before it is registered
  // and fused, and after fusion sweeps fusion.deform_points_per_frame points of the others.
  MapDeformation& deformation() { return deformation_; }
  const MapDeformation& deformation() const { return deformation_; }
  // The whole map in the current version (export, evaluation): what map() users that need every
  // chunk consistent call first. Returns the points brought up to date.
  size_t bring_all_up_to_date() { return deformation_.bring_all_up_to_date(map_.get()); }

  PointMap& map() { return *map_; }
  const PointMap& map() const { return *map_; }
  // Replaces the map (resume from a checkpoint); frame ids continue from next_frame_id.
  void reset(std::unique_ptr<PointMap> map, uint32_t next_frame_id,
             const std::optional<Pose>& last_T_world_cam);
  const std::optional<Pose>& last_pose() const { return last_T_world_cam_; }

  // Relocalisation keyframes for a resumed scan (after reset(), which empties them): frames stored
  // with the poses they were fused at put back as keyframes, so that a camera that moved while the
  // scan was down can be found again. Stored frames are offered newest first (where the camera
  // was last is likeliest to be where it is), each older than the keyframes already held:
  //  - keyframe_wanted: whether a frame at T_world_cam would be kept, by the spacing rule of a
  //    tracked frame and while there is room (max_keyframes), from the pose alone: only the frames
  //    wanted need decoding. False when relocalisation is off or there is no registration.
  //  - restore_keyframe: measures the frame as process() does (back-projection, normals,
  //    pre-filter) and makes it a keyframe at T_world_cam by the same code as a tracked frame.
  //    False when it is not kept (not wanted, or too few points); an error only when the frame
  //    cannot be measured.
  bool keyframe_wanted(const Pose& T_world_cam) const;
  Result<bool> restore_keyframe(const Frame& frame, const Pose& T_world_cam, uint32_t frame_id);
  size_t keyframe_count() const;
  uint32_t next_frame_id() const { return next_frame_id_; }
  const ReconstructionConfig& config() const { return config_; }
  // The mean model fitness (RegistrationResult::model_fitness) of the last frames tracked without a
  // hint, 1 before any: what a correctly placed frame of this sensor and scene scores, the scale of
  // the lost rule's and the relocalisation's model-fitness threshold (classify_tracking()).
  double model_fitness_reference() const;

 private:
  // The frame's measurements into scratch_ (its rolling shutter undone with the motion of the last
  // two frames fused, unless it has a hint): how many the pre-filter removed.
  Result<size_t> measure(const Frame& frame);
  // Registration of the measured frame (scratch_) against the map from `*T_world_cam` (the initial
  // pose), which it replaces by the registered pose: tracking without a hint (with a second start
  // from the last pose after a poor track, and the relocaliser after a loss), refinement with one.
  void register_frame(const Frame& frame, const std::optional<Pose>& prediction, Pose* T_world_cam,
                      FrameReport* report);
  // A poor track from the prediction starts again from the last refined pose (with the same motion
  // prior, if any); the start with the lower mean cost is kept.
  void retry_from_last_pose(const MotionPrior* prior, FrameReport* report);
  // The motion model's prior for a frame at `utime` predicted at `prediction`
  // (registration.motion_prior), none without a prediction.
  std::optional<MotionPrior> motion_prior(int64_t utime,
                                          const std::optional<Pose>& prediction) const;
  // After a frame tracked with the prior: its prediction error, in the directions its depth
  // measured itself, updates the spread of the motion model's errors.
  void learn_motion(const MotionPrior& prior, const RegistrationResult& r);
  // The keyframes' candidates for a lost frame, each tracked against the map; the first that
  // tracks well is the frame's pose.
  // `utime`: the frame's, for how far the camera can have gone since the last frame placed.
  void relocalise(int64_t utime, FrameReport* report);
  // Whether the camera can have got to T_world_cam by `utime` from the last frame placed
  // (RelocalisationConfig::max_speed_m_s, max_turn_deg_s); true before any.
  bool reachable(const Pose& T_world_cam, int64_t utime) const;
  bool keeps_keyframes() const;
  // After a frame tracked without a hint at T_world_cam: the relocaliser's keyframes, and the
  // model fitness the lost rule is scaled by.
  void note_tracked(const Frame& frame, const Pose& T_world_cam, const FrameReport& report);
  // Where the camera's motion was steady: the velocity of the last two frames fused, in the
  // camera frame of the last; none across a gap of more than a few frame periods.
  std::optional<CameraVelocity> camera_velocity_through_next(int64_t utime) const;
  struct StampedPose {
    int64_t utime = 0;
    Pose T_world_cam = Pose::Identity();
  };
  // Whether `before` and `last` are at most max_gap_us apart, and `utime` is after the last by at
  // most that: the last step may be carried on to it.
  static bool step_spans(const std::optional<StampedPose>& before,
                         const std::optional<StampedPose>& last, int64_t utime, int64_t max_gap_us);
  // A frame placed at T_world_cam: the motion model's. fused_at() also the rolling shutter's.
  void placed_at(int64_t utime, const Pose& T_world_cam);
  void fused_at(int64_t utime, const Pose& T_world_cam);

  ReconstructionConfig config_;
  std::unique_ptr<PointMap> map_;
  MapDeformation deformation_;
  Fuser fuser_;
  Registrar registrar_;
  std::unique_ptr<Relocaliser> relocaliser_;
  MeasurementImage scratch_;
  int frames_since_model_ = 0;  // frames registered to the Registrar's last rendered model
  uint32_t model_version_ = 0;  // the map's version (MapDeformation) when it was rendered
  std::optional<Pose> last_T_world_cam_;
  // The last two frames placed (fused or tracked only), stamped: the motion model's prediction,
  // its prior and the relocaliser's reach.
  std::optional<StampedPose> placed_before_last_, placed_last_;
  // The last two frames fused: the camera's velocity through the next frame, for a rolling shutter
  // (camera_velocity_through_next()). Fused frames only, so that a resume, which replays the fused
  // frames (replay()), measures each as it was measured live.
  std::optional<StampedPose> fused_before_last_, fused_last_;
  uint32_t next_frame_id_ = 1;
  // The motion model's squared prediction error per frame period, per axis of the camera frame
  // (pose_delta.hpp), a running mean over the last frames that measured it; before any, a loose
  // five times the floor (initial_motion_error_sq()). `motion_measured_`: the axes some frame's
  // depth has measured since the track began (motion_prior() pools the translation axes').
  Vector6d initial_motion_error_sq() const;
  Vector6d motion_error_sq_;
  std::array<bool, 6> motion_measured_{};
  // The model fitness of the last tracked frames (a ring; model_fitness_reference()).
  std::array<float, 8> recent_model_fitness_{};
  size_t recent_model_fitness_count_ = 0;
};

}  // namespace depthfuse
