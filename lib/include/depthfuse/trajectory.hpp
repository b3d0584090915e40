// TUM trajectory files: "timestamp tx ty tz qx qy qz qw" per line, camera-to-world.
#pragma once

#include <cstdio>
#include <string>
#include <vector>

#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse {

// Rejects NaN/inf, non-numeric fields, wrong field counts and non-unit quaternions (|q| off by
// more than 1e-3) with the file name and line number; normalises the quaternion.
Result<std::vector<StampedPose>> read_tum_trajectory(const std::string& path);
Status write_tum_trajectory(const std::string& path, const std::vector<StampedPose>& poses);

// The same file written pose by pose, for a sequence too long to hold its trajectory.
class TumTrajectoryWriter {
 public:
  TumTrajectoryWriter() = default;
  TumTrajectoryWriter(const TumTrajectoryWriter&) = delete;
  TumTrajectoryWriter& operator=(const TumTrajectoryWriter&) = delete;
  ~TumTrajectoryWriter();

  Status open(const std::string& path);  // creates (or truncates) the file, writes the header
  void add(const StampedPose& pose);
  Status close();                        // errors of any write since open() are reported here

 private:
  std::FILE* file_ = nullptr;
  std::string path_;
};

// Index of the pose nearest in time to t_s, if within max_dt_s; -1 otherwise. poses sorted by time.
long nearest_pose(const std::vector<StampedPose>& poses, double t_s, double max_dt_s);

// Absolute trajectory error (RMSE of translation) after the best rigid alignment (Horn/Umeyama
// without scale), as the TUM benchmark reports it. Also returns the unaligned RMSE.
struct AteResult {
  double rmse_m = 0, mean_m = 0, max_m = 0;
  double unaligned_rmse_m = 0;
  size_t pairs = 0;
  Pose T_truth_estimate = Pose::Identity();  // the rigid alignment used (estimate -> truth frame)
};
Result<AteResult> absolute_trajectory_error(const std::vector<Pose>& T_world_cam_estimate,
                                            const std::vector<Pose>& T_world_cam_truth);

// The rigid motion (estimate -> truth frame) that best aligns the cameras themselves: each pose
// contributes its position and the points view_m in front of it along its three axes. Where a
// path is nearly straight or planar, positions alone leave a rotation about it free, and the ATE's
// alignment picks one from the noise; a cloud placed with it would carry that rotation as error.
// The cameras' orientations pin it.
Result<Pose> align_cameras(const std::vector<Pose>& T_world_cam_estimate,
                           const std::vector<Pose>& T_world_cam_truth, double view_m = 1.0);

}  // namespace depthfuse
