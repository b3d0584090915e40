// The keyframes and pose graph of a scan tracked without pose hints. A frame becomes a keyframe when
// the camera has moved far enough since the last one; consecutive keyframes are joined by an
// odometry edge whose information is the tracking's own (the registration's normal equations and
// the motion prior, accumulated over the frames between), so that a direction the depth did not
// see carries no weight; the loop closer (loop_closure.hpp) adds loop edges and optimises, and
// apply() moves the keyframes where the optimiser put them. Every fused frame belongs to the last
// keyframe before it, and moves with it.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "depthfuse/config.hpp"
#include "depthfuse/measurement.hpp"
#include "depthfuse/pose_delta.hpp"
#include "depthfuse/pose_graph.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse {

// What a keyframe saw, for verifying a loop closure: its valid measurements averaged in cubes
// (LoopClosureConfig::voxel_m), with normals, in its camera frame; and its depth thumbnail, for
// the place search.
struct KeyframeCloud {
  std::vector<Eigen::Vector3f> position_m;
  std::vector<Eigen::Vector3f> normal;
  std::array<float, 16 * 12> thumbnail{};  // thumbnail.hpp's layout

  size_t size() const { return position_m.size(); }
  size_t memory_bytes() const;
};

KeyframeCloud make_keyframe_cloud(const MeasurementImage& m, const LoopClosureConfig& config);

struct GraphKeyframe {
  uint32_t frame_id = 0;    // the frame that became it; its segment runs to the next keyframe's
  int64_t utime = 0;
  Pose T_world_kf = Pose::Identity();
  std::shared_ptr<const KeyframeCloud> cloud;  // shared with the loop closer's snapshots

  // False once it gave its points up (ScanGraph::forget_redundant_clouds): no closure candidate.
  bool has_points() const { return cloud && cloud->size() > 0; }
};

// The loop closer's result: the optimised poses of keyframes [0, T_world_kf.size()) of the graph it
// was given, and the loop edges it holds (every one it believes, older ones too).
struct GraphCorrection {
  std::vector<Pose> T_world_kf;
  std::vector<PoseGraphEdge> loops;
};

// A correction once applied: how each keyframe, and so each of its frames, moved.
struct AppliedCorrection {
  uint32_t version = 0;
  std::vector<uint32_t> first_frame_id;  // per keyframe: its segment's first frame
  std::vector<Pose> motion;              // per keyframe: T_world_kf(new) * T_world_kf(old)^-1
  double max_translation_m = 0;          // the largest keyframe motion
  size_t loops = 0;                      // loop edges in the graph after it

  // The motion of the keyframe that `frame_id` belongs to (identity before the first keyframe).
  const Pose& motion_of(uint32_t frame_id) const;
};

// What the loop closer has done (loop_closure.hpp).
struct LoopClosureStats {
  uint64_t keyframes_searched = 0;
  uint64_t candidates = 0;       // verified by ICP
  uint64_t aligned = 0;          // ICP converged with enough overlap and a small residual
  uint64_t gated = 0;            // aligned, but beyond the odometry's uncertainty: refused
  uint64_t place_searches = 0;   // FPFH and sample consensus runs
  uint64_t loops = 0;            // loop edges the optimiser kept
  uint64_t rejected = 0;         // loop edges the optimiser rejected
  uint64_t optimisations = 0;
  // Keyframes whose new loops all agreed with the graph as it stood: kept, no optimisation run.
  uint64_t loops_agreed = 0;
  double seconds = 0;            // thread time spent
};

// A ScanGraph as plain data, for the scan file (ScanGraph::state(), ScanGraph::restore()).
struct ScanGraphState {
  std::vector<GraphKeyframe> keyframes;
  std::vector<PoseGraphEdge> odometry;       // i -> i + 1
  std::vector<Matrix6d> odometry_covariance;  // each odometry edge's, its information's inverse
  std::vector<PoseGraphEdge> loops;
  uint32_t version = 0;
};

class ScanGraph {
 public:
  explicit ScanGraph(const LoopClosureConfig& config);

  // A frame fused without a pose hint, at T_world_cam with the covariance of its pose
  // (RegistrationResult::covariance, camera frame; the first frame, placed by definition: zero).
  // Returns true when it became a keyframe (keyframes().back()).
  bool frame_fused(uint32_t frame_id, int64_t utime, const Pose& T_world_cam,
                   const Matrix6d& covariance, const MeasurementImage& m);
  // A frame tracked without a hint but not fused (FrameWork::kTrackOnly): its pose's uncertainty
  // adds to the next keyframe's odometry edge as a fused frame's does; it is never a keyframe (a
  // keyframe's points are in the map).
  void frame_tracked(const Pose& T_world_cam, const Matrix6d& covariance);
  AppliedCorrection apply(const GraphCorrection& correction);
  // Keyframes [0, searched) have been searched for loops (LoopCloser::searched()). While the
  // keyframes' clouds take more than loop_closure.max_cloud_mib, each of them in turn, once, gives
  // up its points (not its thumbnail) when an older keyframe that kept its own has its camera within
  // loop_closure.cloud_spacing_m and _deg: later closures at that place are found against the
  // older one. Returns how many gave them up.
  size_t forget_redundant_clouds(size_t searched);

  const std::vector<GraphKeyframe>& keyframes() const { return keyframes_; }
  // Odometry edges (i -> i + 1) and the covariance each was made from, and the loop edges.
  const std::vector<PoseGraphEdge>& odometry() const { return odometry_; }
  const std::vector<Matrix6d>& odometry_covariance() const { return odometry_covariance_; }
  const std::vector<PoseGraphEdge>& loops() const { return loops_; }
  uint32_t version() const { return version_; }  // corrections applied
  size_t memory_bytes() const;
  void clear();

  ScanGraphState state() const;
  // Replaces the graph by `s` (a resumed scan); the next frame's uncertainty is accumulated from
  // the last keyframe. An error (edges that do not join keyframes i and i + 1, a loop edge out of
  // range, frame ids out of order, a missing cloud) changes nothing. Its keyframes have been
  // searched: their redundant clouds go (forget_redundant_clouds), as they did before the restart.
  Status restore(ScanGraphState s);

 private:
  LoopClosureConfig config_;
  std::vector<GraphKeyframe> keyframes_;
  std::vector<PoseGraphEdge> odometry_, loops_;
  std::vector<Matrix6d> odometry_covariance_;
  // The covariance of the last placed frame's pose relative to the last keyframe, in its frame.
  Matrix6d since_keyframe_ = Matrix6d::Zero();
  std::optional<Pose> last_placed_;
  uint32_t version_ = 0;
  size_t clouds_checked_ = 0;  // forget_redundant_clouds() has looked at keyframes [0, this)
};

}  // namespace depthfuse
