// Camera paths of the built-in scenes, each a closed-form function of the frame index.
#include "depthfuse/synthetic/trajectory.hpp"

#include <array>
#include <cmath>

#include "lap_rooms.hpp"
#include "rooms_layout.hpp"

namespace depthfuse::synthetic {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

using Eigen::Vector2d;
using Eigen::Vector3d;

// A camera at eye looking along yaw (from +x towards +y) and pitch (up positive).
Pose look_along(const Vector3d& eye, double yaw_rad, double pitch_rad) {
  const Vector3d dir(std::cos(yaw_rad) * std::cos(pitch_rad),
                     std::sin(yaw_rad) * std::cos(pitch_rad), std::sin(pitch_rad));
  return look_at(eye, eye + dir);
}

// --- corner: an arc around a pivot in front of the corner, looking into it.
Pose corner_pose(size_t i, size_t frames) {
  const double s = frames > 1 ? static_cast<double>(i) / static_cast<double>(frames - 1) : 0.5;
  const double azimuth = s * 0.5 * kPi;  // 0..90 degrees, from the x = 0 wall's normal side
  const double radius = 1.4 + 0.1 * std::sin(kPi * s);
  const Vector3d pivot(0.6, 0.6, 0.0);
  const Vector3d eye = pivot + Vector3d(radius * std::cos(azimuth), radius * std::sin(azimuth),
                                        1.2 + 0.1 * std::sin(2.0 * kPi * s));
  return look_at(eye, Vector3d(0.25, 0.25, 0.6));
}

// --- room: an ellipse around the room centre, looking across the room (through its centre) and
// down, so that walls and the boxes in front of them are seen from 2.5-3.5 m.
Pose room_pose(size_t i, size_t frames) {
  const double s = static_cast<double>(i) / static_cast<double>(frames);  // closed loop
  const double phi = 2.0 * kPi * s;
  const Vector3d eye(2.5 + 0.7 * std::cos(phi), 2.0 + 0.45 * std::sin(phi),
                     1.3 + 0.05 * std::sin(3.0 * phi));
  return look_along(eye, phi + kPi + 0.2 * std::sin(2.0 * phi), -25.0 * kDeg);
}

// --- rooms: a closed tour through all rooms.
struct TourPiece {
  Vector2d door_in;  // where the piece starts (middle of a doorway)
  Vector2d dir_in;   // heading there (unit, axis-aligned)
  Vector2d dir_out;  // heading at the end
  double length_m;   // 5 m straight or a quarter circle of radius 2.5 m
  double start_m;    // cumulative length before this piece
};

// Rooms in tour order (a Hamiltonian cycle of the 4 x 4 grid).
constexpr std::array<std::array<int, 2>, 16> kTour = {{{0, 0},
                                                       {1, 0},
                                                       {2, 0},
                                                       {3, 0},
                                                       {3, 1},
                                                       {2, 1},
                                                       {1, 1},
                                                       {1, 2},
                                                       {2, 2},
                                                       {3, 2},
                                                       {3, 3},
                                                       {2, 3},
                                                       {1, 3},
                                                       {0, 3},
                                                       {0, 2},
                                                       {0, 1}}};
static_assert(rooms_layout::kRoomsN == 4, "the tour is written for 4 x 4 rooms");

struct Tour {
  std::array<TourPiece, kTour.size()> pieces;
  double length_m = 0.0;
};

Vector2d room_center(const std::array<int, 2>& r) {
  return Vector2d((r[0] + 0.5) * rooms_layout::kCellM, (r[1] + 0.5) * rooms_layout::kCellM);
}

Tour build_tour() {
  Tour tour;
  const size_t n = kTour.size();
  double acc = 0.0;
  for (size_t k = 0; k < n; ++k) {
    const Vector2d prev = room_center(kTour[(k + n - 1) % n]);
    const Vector2d cur = room_center(kTour[k]);
    const Vector2d next = room_center(kTour[(k + 1) % n]);
    TourPiece& p = tour.pieces[k];
    p.door_in = 0.5 * (prev + cur);
    p.dir_in = (cur - prev).normalized();
    p.dir_out = (next - cur).normalized();
    const double half = 0.5 * rooms_layout::kCellM;
    p.length_m = p.dir_in.dot(p.dir_out) > 0.5 ? 2.0 * half : 0.5 * kPi * half;
    p.start_m = acc;
    acc += p.length_m;
  }
  tour.length_m = acc;
  return tour;
}

const Tour& tour() {
  static const Tour t = build_tour();
  return t;
}

// Position and heading at arc length s along piece p.
void tour_point(const TourPiece& p, double s, Vector2d* pos, Vector2d* heading) {
  if (p.dir_in.dot(p.dir_out) > 0.5) {
    *pos = p.door_in + s * p.dir_in;
    *heading = p.dir_in;
    return;
  }
  // Quarter circle around the room corner c = door_in + r * dir_out:
  //   x(a) = c + r (-dir_out cos a + dir_in sin a), a in [0, pi/2].
  const double r = 0.5 * rooms_layout::kCellM;
  const Vector2d c = p.door_in + r * p.dir_out;
  const double a = s / r;
  *pos = c + r * (-p.dir_out * std::cos(a) + p.dir_in * std::sin(a));
  *heading = p.dir_out * std::sin(a) + p.dir_in * std::cos(a);
}

constexpr double kWalkSpeedMps = 0.5;
constexpr double kEyeHeightM = 1.5;

Pose rooms_pose(size_t i, double rate_hz) {
  const Tour& t = tour();
  const double time_s = static_cast<double>(i) / rate_hz;
  // Start in the middle of the second room (straight through it), not in a doorway.
  const double start_m = t.pieces[1].start_m + 0.5 * t.pieces[1].length_m;
  const double s = std::fmod(start_m + kWalkSpeedMps * time_s, t.length_m);
  size_t k = 0;
  while (k + 1 < t.pieces.size() && t.pieces[k + 1].start_m <= s) ++k;
  Vector2d pos, heading;
  tour_point(t.pieces[k], s - t.pieces[k].start_m, &pos, &heading);
  const double yaw =
      std::atan2(heading.y(), heading.x()) + 50.0 * kDeg * std::sin(2.0 * kPi * time_s / 9.0);
  const double pitch = -20.0 * kDeg + 5.0 * kDeg * std::sin(2.0 * kPi * time_s / 5.3);
  const Vector3d eye(pos.x(), pos.y(), kEyeHeightM + 0.02 * std::sin(2.0 * kPi * time_s * 1.8));
  return look_along(eye, yaw, pitch);
}

}  // namespace

Pose look_at(const Eigen::Vector3d& eye_w, const Eigen::Vector3d& target_w,
             const Eigen::Vector3d& up_w) {
  const Vector3d z = (target_w - eye_w).normalized();
  const Vector3d x = z.cross(up_w).normalized();
  const Vector3d y = z.cross(x);
  Pose T = Pose::Identity();
  T.linear().col(0) = x;
  T.linear().col(1) = y;
  T.linear().col(2) = z;
  T.translation() = eye_w;
  return T;
}

Trajectory::Trajectory(SceneKind kind, size_t frames, double rate_hz)
    : kind_(kind), frames_(frames > 0 ? frames : 1), rate_hz_(rate_hz > 0.0 ? rate_hz : 30.0) {}

Pose Trajectory::T_world_cam(size_t i) const {
  switch (kind_) {
    case SceneKind::kCorner:
      return corner_pose(i, frames_);
    case SceneKind::kRoom:
      return room_pose(i, frames_);
    case SceneKind::kRooms:
      return rooms_pose(i, rate_hz_);
    case SceneKind::kFurnished:
    case SceneKind::kPlain:
      return lap_rooms::lap_walk_pose(i, rate_hz_);
  }
  return Pose::Identity();
}

double Trajectory::rooms_tour_length_m() { return tour().length_m; }

}  // namespace depthfuse::synthetic
