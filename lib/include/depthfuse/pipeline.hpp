// The paper's method end to end, in the two shapes depthfuse needs:
//  - IncrementalReconstructor: one frame at a time into a growing map (the fusion daemon);
//  - reconstruct_batch: the outer loop over a whole sequence (fuse, re-register, fuse again).
#pragma once

#include <array>
#include <chrono>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "depthfuse/config.hpp"
#include "depthfuse/fusion.hpp"
#include "depthfuse/measurement.hpp"
#include "depthfuse/point_map.hpp"
#include "depthfuse/registration.hpp"
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
  // Without a pose hint, how far the tracked pose can be trusted (classify_tracking()); with one,
  // tracked if its ICP converged, else uncertain (the hint is fused). A lost frame is not fused.
  TrackingState tracking = TrackingState::kTracked;
  bool fused() const { return tracking != TrackingState::kLost; }
  RegistrationResult registration;
  FusionStats fusion;
  size_t prefiltered = 0;                // measurements the pre-filter removed
  double prefilter_ms = 0, registration_ms = 0, fusion_ms = 0;
  double relocalisation_ms = 0;          // the keyframe search, part of registration_ms
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

  // Pre-filter; initial pose (the frame's hint if any, otherwise the given prediction, otherwise
  // the last refined pose); re-registration against the map (if the method has it and the map is
  // not empty); fusion. With a hint, ICP refines it; without one, coarse-to-fine tracking runs.
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
  // stays that of the last frame fused.
  Result<FrameReport> process(const Frame& frame,
                              const std::optional<Pose>& T_world_cam_prediction = std::nullopt);
  // For a live stream, whose frames carry the sensor's times and may be dropped on the way: the
  // pose at `utime` if the camera kept the motion of the last two frames fused, that motion scaled
  // to the time since the last. None before two frames, or across a gap of more than a few frame
  // periods (the same rule as the rolling-shutter velocity's).
  std::optional<Pose> constant_velocity_prediction(int64_t utime) const;

  // Fuses `frame` at `T_world_cam` as frame `frame_id`, with no registration: a frame that was
  // fused before (a scan's frame redo log after a crash). Fusion is the same as process()'s, so
  // the map becomes what it was; frame ids continue after frame_id, the last pose is T_world_cam,
  // and the next frame renders its own model.
  Status replay(const Frame& frame, uint32_t frame_id, const Pose& T_world_cam);

  // Post-filter the whole map (end of scan).
  size_t finish();

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
  Result<bool> restore_keyframe(const Frame& frame, const Pose& T_world_cam);
  size_t keyframe_count() const;
  uint32_t next_frame_id() const { return next_frame_id_; }
  const ReconstructionConfig& config() const { return config_; }
  // The mean model fitness (RegistrationResult::model_fitness) of the last frames tracked without a
  // hint, 1 before any: what a correctly placed frame of this sensor and scene scores, the scale of
  // the lost rule's and the relocalisation's model-fitness threshold (classify_tracking()).
  double model_fitness_reference() const;

 private:
  // The keyframes' candidates for a lost frame, each tracked against the map; the first that
  // tracks well is the frame's pose.
  void relocalise(FrameReport* report);
  bool keeps_keyframes() const;
  // Where the camera's motion was steady: the velocity of the last two frames fused, in the
  // camera frame of the last; none across a gap of more than a few frame periods.
  std::optional<CameraVelocity> camera_velocity_through_next(int64_t utime) const;
  void fused_at(int64_t utime, const Pose& T_world_cam);

  ReconstructionConfig config_;
  std::unique_ptr<PointMap> map_;
  Fuser fuser_;
  Registrar registrar_;
  std::unique_ptr<Relocaliser> relocaliser_;
  MeasurementImage scratch_;
  int frames_since_model_ = 0;  // frames registered to the Registrar's last rendered model
  std::optional<Pose> last_T_world_cam_;
  // The last two frames fused, stamped: the camera's velocity through the next frame, for a
  // rolling shutter (camera_velocity_through_next()).
  struct StampedPose {
    int64_t utime = 0;
    Pose T_world_cam = Pose::Identity();
  };
  std::optional<StampedPose> fused_before_last_, fused_last_;
  uint32_t next_frame_id_ = 1;
  // The model fitness of the last tracked frames (a ring; model_fitness_reference()).
  std::array<float, 8> recent_model_fitness_{};
  size_t recent_model_fitness_count_ = 0;
};

// Progress of a long run: stage name, done, total.
using ProgressFn = std::function<void(const std::string& stage, size_t done, size_t total)>;

struct BatchIterationReport {
  int iteration = 0;                    // 0 = first fusion with the initial poses
  size_t points = 0;
  double max_translation_change_m = 0;  // pose change made by this iteration's re-registration
  double max_rotation_change_deg = 0;
  size_t registered = 0;                // frames whose re-registration converged; the rest kept
                                        // their pose (too few pairs)
  double mean_fitness = 0;              // over the registered frames
  double mean_rmse_m = 0;
  double seconds = 0;
};

struct BatchResult {
  std::unique_ptr<PointMap> map;
  std::vector<Pose> T_world_cam;         // refined poses, one per frame
  std::vector<BatchIterationReport> iterations;
  size_t input_measurements = 0;         // valid depth pixels of all frames (before pre-filter)
  size_t prefiltered = 0;                // removed by the pre-filter (last fusion)
  size_t postfiltered = 0;               // removed by the post-filter
  bool converged_early = false;
};

// One fusion pass of the batch pipeline, frame by frame: each frame pre-filtered and fused with
// the pose given into a fresh map. Without re-registration rounds (outer_iterations 0, or a method
// without registration) it is the whole pipeline, and a sequence streams through it from its
// source with nothing held per frame.
class SequenceFuser {
 public:
  // The config as reconstruct_batch takes it (its method is applied here).
  explicit SequenceFuser(const ReconstructionConfig& config);
  ~SequenceFuser();

  // `velocity` (the camera's during the frame, where known) undoes a rolling shutter.
  Status add(const Frame& frame, const Pose& T_world_cam, const CameraVelocity* velocity = nullptr);
  size_t frames() const { return frames_; }
  size_t measurements() const { return measurements_; }  // valid depth pixels (before pre-filter)
  size_t prefiltered() const { return prefiltered_; }
  // The map as fused, for the next pass.
  std::unique_ptr<PointMap> take_map() { return std::move(map_); }
  // The end of a pipeline without rounds: the map post-filtered (if the method has it) and the
  // one pass's figures. T_world_cam stays empty: the poses were the caller's.
  BatchResult finish();

 private:
  ReconstructionConfig config_;
  std::unique_ptr<PointMap> map_;
  Fuser fuser_;
  MeasurementImage scratch_;
  size_t frames_ = 0, measurements_ = 0, prefiltered_ = 0;
  std::chrono::steady_clock::time_point start_;
};

// The paper's batch pipeline. frames[i] is fused with T_world_cam_initial[i]. With method full it
// runs config.pipeline.outer_iterations rounds of re-registration + fusion, stopping early when
// the poses stop moving.
Result<BatchResult> reconstruct_batch(const std::vector<Frame>& frames,
                                      const std::vector<Pose>& T_world_cam_initial,
                                      const ReconstructionConfig& config,
                                      const ProgressFn& progress = nullptr);

struct TrackedSequence {
  std::vector<Pose> T_world_cam;       // one per frame; a lost frame's is ICP's best guess
  std::vector<TrackingState> state;    // one per frame
  size_t uncertain = 0, lost = 0;      // frames in those states
  size_t relocalised = 0;              // frames found among the keyframes after a loss
};

// Poses for a sequence without any: frame-to-model tracking from the first frame (at identity),
// each frame from a constant-velocity prediction (the last two frames fused), or from the last
// frame fused after a loss.
Result<TrackedSequence> track_sequence(const std::vector<Frame>& frames,
                                       const ReconstructionConfig& config,
                                       const ProgressFn& progress = nullptr);

}  // namespace depthfuse
