// The paper's batch pipeline over a whole sequence: one fusion pass (SequenceFuser), the outer loop
// of re-registration and fusion (reconstruct_batch), and poses for a sequence without any
// (track_sequence, the rig's per-frame path).
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "depthfuse/incremental.hpp"

namespace depthfuse {

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
  size_t ambiguous = 0;                // places found for them and refused: another fits too
  size_t keyframes = 0, loops = 0;     // the pose graph's
  size_t corrections = 0;              // loop closures that moved the poses
};

// Poses for a sequence without any: frame-to-model tracking from the first frame (at identity),
// every frame through the rig's own per-frame path (FramePath, without a store), its hint ignored,
// loops closed as they are found and once more at the end: the poses are the pose graph's.
Result<TrackedSequence> track_sequence(const std::vector<Frame>& frames,
                                       const ReconstructionConfig& config,
                                       const ProgressFn& progress = nullptr);

}  // namespace depthfuse
