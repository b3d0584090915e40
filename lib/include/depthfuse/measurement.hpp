// A depth frame back-projected into camera-frame points with normals, and the paper's pre-filter.
#pragma once

#include <cstdint>
#include <vector>

#include "depthfuse/config.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse {

// Per-pixel structure-of-arrays; reused from frame to frame (resize only when the size changes).
struct MeasurementImage {
  int width = 0;
  int height = 0;
  CameraIntrinsics intrinsics;
  std::vector<float> x, y, z;     // camera frame, metres; z == depth
  std::vector<float> nx, ny, nz;  // unit normal facing the camera; 0 when unknown
  std::vector<uint8_t> valid;     // 1 = usable measurement

  size_t pixel_count() const { return x.size(); }
  size_t valid_count() const;
  void resize(int w, int h);
};

// Back-projects a depth frame (depth outside [min_depth_m, max_depth_m] is invalid) and computes
// normals by central differences. Fails on a frame whose size disagrees with its intrinsics.
Status backproject(const Frame& frame, const SensorModelConfig& sensor, const FusionConfig& fusion,
                   MeasurementImage* out);

// How the camera moved while a frame was taken: its angular and linear velocity in its own frame
// (rad/s, m/s), as a pose sequence gives it.
struct CameraVelocity {
  Eigen::Vector3d omega_cam_rad_s = Eigen::Vector3d::Zero();
  Eigen::Vector3d v_cam_m_s = Eigen::Vector3d::Zero();
};

// The velocity that takes the camera from T_world_cam_from to T_world_cam_to in dt_s seconds,
// expressed in the camera frame at T_world_cam_at.
CameraVelocity camera_velocity(const Pose& T_world_cam_from, const Pose& T_world_cam_to, double dt_s,
                               const Pose& T_world_cam_at);

// The camera's velocity at each frame from its neighbours' poses and stamps (central differences;
// one-sided at the ends; zero for a single frame or frames without increasing stamps).
std::vector<CameraVelocity> camera_velocities(const std::vector<Frame>& frames,
                                              const std::vector<Pose>& T_world_cam);

// The depth image a rolling-shutter camera (intrinsics.row_readout_s > 0) moving at `velocity`
// would have taken had every row been exposed at the middle row's time: each pixel's point is
// moved by the camera's motion between its row's time and the middle row's, and the image is
// resampled (nearest pixel, backward warp) so that every pixel keeps its own ray. Returns false and
// leaves *out alone when there is nothing to do (a global shutter, or no motion).
bool undo_rolling_shutter(const Frame& frame, const CameraVelocity& velocity, DepthImage* out);
// The same with the readout time given (`readout_s`), for a frame that does not carry its own.
bool undo_rolling_shutter(const Frame& frame, const CameraVelocity& velocity, double readout_s,
                          DepthImage* out);
// The rows' readout time of `frame`: its own, or where it carries none, the sensor's.
double row_readout_s(const Frame& frame, const SensorModelConfig& sensor);

// d_r(z) / z for these intrinsics: the mean distance from a point to its k-th nearest neighbour
// on a fronto-parallel plane at 1 m, found by back-projecting a constant depth map (d_r is linear
// in z for a pinhole camera).
double reference_knn_distance_per_m(const CameraIntrinsics& intrinsics, int neighbour_rank,
                                    int window_radius_px);

// The paper's pre-filter (eq. 1). Marks removed measurements invalid; returns how many. With two
// threads the two halves of the rows are tested at once; the result is the same.
size_t prefilter(const PrefilterConfig& config, MeasurementImage* m, int threads = 1);

}  // namespace depthfuse
