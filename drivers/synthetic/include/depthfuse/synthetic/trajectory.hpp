// Camera paths through the built-in scenes. The pose of frame i is computed in O(1) from i alone
// (no per-frame table), so a 36000-frame walk costs nothing until it is rendered.
// Poses are T_world_cam with the optical camera frame: x right, y down, z forward.
#pragma once

#include <cstddef>

#include "depthfuse/synthetic/scene.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::synthetic {

// A camera at eye_w looking at target_w, image "up" towards world +z (target not straight above or
// below the eye).
Pose look_at(const Eigen::Vector3d& eye_w, const Eigen::Vector3d& target_w,
             const Eigen::Vector3d& up_w = Eigen::Vector3d::UnitZ());

class Trajectory {
 public:
  Trajectory() = default;
  // frames: the sequence length; rate_hz: frames per second (the rooms and lap walks have a fixed
  // pace, so their length in metres follows frames / rate_hz).
  Trajectory(SceneKind kind, size_t frames, double rate_hz);

  //  corner: a 90 degree arc (azimuth 0..90 deg) of radius 1.4-1.5 m around a point 0.6 m in
  //          front of both walls, 1.1-1.3 m high, always looking into the corner, 2.1-2.4 m from
  //          its vertical axis.
  //  room:   one closed loop (an ellipse around the room centre) looking across the room at the
  //          opposite walls and boxes, 25 degrees down; the last frame comes back next to the
  //          first.
  //  rooms:  walking at 0.5 m/s along a closed tour through all 16 rooms (straight through a
  //          room or a quarter circle around one of its corners), head swinging +-50 degrees and
  //          looking 20 degrees down; the tour is ~71 m, so 20 minutes go around it about eight
  //          times, revisiting every room.
  //  furnished, plain: a handheld walk of laps around the middle of the room (a loop of about
  //          1.3 x 1.2 m, a little north of the middle, that drifts from lap to lap), looking
  //          outwards at the walls and the furniture, 1.3-1.5 m high and about 18 degrees down; a
  //          lap takes about 18.5 s (560 frames at 30 Hz: 7 mm and 0.65 degrees a frame on
  //          average), the speed varies and falls to a short stop every 23 s; a handheld's sway
  //          in height, pitch (+-5 degrees) and roll (+-3 degrees), a walking bob and a small fast
  //          jitter. The length sets the laps: 1,200 frames go twice round and back past the
  //          start, 20 minutes about 64 times.
  Pose T_world_cam(size_t i) const;

  SceneKind kind() const { return kind_; }
  size_t frames() const { return frames_; }

  // Length of one tour of the rooms walk in metres.
  static double rooms_tour_length_m();

 private:
  SceneKind kind_ = SceneKind::kCorner;
  size_t frames_ = 1;
  double rate_hz_ = 30.0;
};

}  // namespace depthfuse::synthetic
