// The handheld walk of the furnished and plain rooms: laps around the middle of the room, looking
// outwards at the walls and the furniture, as an operator scans a room. Closed-form in the time,
// so a frame's pose costs the same whatever its index (no tables).
//
// The walker's progress round the loop is an angle theta about the loop's centre. It advances
// with a speed that varies (two slow sinusoids, between 0.45 and 1.55 times the mean) and falls
// to nothing at a short stop every kStopPeriodS; the loop's semi-axes and centre drift with theta
// at frequencies that are not multiples of a lap, so that no lap repeats another. On top: a
// handheld's slow sway in height, pitch and roll, a walking bob that stops when the walker does,
// and a small fast jitter.
#include <cmath>

#include "depthfuse/synthetic/trajectory.hpp"
#include "lap_rooms.hpp"

namespace depthfuse::synthetic::lap_rooms {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kTwoPi = 2.0 * kPi;
constexpr double kDeg = kPi / 180.0;

// Mean angular speed while walking: about 18.5 s a lap with the stops (560 frames at 30 Hz), so
// 1,200 frames make two laps and come back past the start.
constexpr double kOmegaRadPerS = 0.36;
constexpr double kStartTheta = -0.5 * kPi - 0.6;  // facing the south-west: the door, the shelf

// Stops: centred at kFirstStopS + k kStopPeriodS; the speed tapers to 0 over kStopTaperS, stays 0
// for 2 kStopHoldS, and comes back the same way.
constexpr double kFirstStopS = 11.0;
constexpr double kStopPeriodS = 23.0;
constexpr double kStopHoldS = 0.3;
constexpr double kStopTaperS = 0.8;

// The share of the speed a stop takes away at time t (1 = standing), relative to its centre.
double stop_share(double dt) {
  const double a = std::fabs(dt);
  if (a <= kStopHoldS) return 1.0;
  if (a >= kStopHoldS + kStopTaperS) return 0.0;
  return 0.5 * (1.0 + std::cos(kPi * (a - kStopHoldS) / kStopTaperS));
}

// Integral of stop_share over (-infinity, dt] for one stop.
double stop_integral_one(double dt) {
  constexpr double h = kStopHoldS, w = kStopTaperS;
  if (dt <= -(h + w)) return 0.0;
  if (dt < -h) {
    const double s = dt + h + w;  // rising: 0.5 (1 - cos(pi s / w))
    return 0.5 * (s - w / kPi * std::sin(kPi * s / w));
  }
  if (dt <= h) return 0.5 * w + (dt + h);
  if (dt < h + w) {
    const double s = dt - h;  // falling: 0.5 (1 + cos(pi s / w))
    return 0.5 * w + 2.0 * h + 0.5 * (s + w / kPi * std::sin(kPi * s / w));
  }
  return w + 2.0 * h;
}

// The nearest stop's centre index for time t (stops never overlap: the period is longer).
double nearest_stop_offset(double t, double* index) {
  const double k = std::floor((t - kFirstStopS) / kStopPeriodS + 0.5);
  *index = k;
  return t - (kFirstStopS + k * kStopPeriodS);
}

// Walking time: t less the time the stops took away.
double walking_time(double t) {
  double k;
  const double dt = nearest_stop_offset(t, &k);
  if (k < 0) return t;  // before the first stop's reach
  return t - (k * (kStopTaperS + 2.0 * kStopHoldS) + stop_integral_one(dt));
}

// The walk's angle after `tau` seconds of walking: speed omega (1 + 0.35 sin(2 pi tau / 13)
// + 0.2 sin(2 pi tau / 5.3 + 1.1)), integrated.
double walk_theta(double tau) {
  constexpr double T1 = 13.0, A1 = 0.35, T2 = 5.3, A2 = 0.2, P2 = 1.1;
  return kStartTheta +
         kOmegaRadPerS * (tau + A1 * T1 / kTwoPi * (1.0 - std::cos(kTwoPi * tau / T1)) +
                          A2 * T2 / kTwoPi * (std::cos(P2) - std::cos(kTwoPi * tau / T2 + P2)));
}

double wave(double t, double period_s, double phase) {
  return std::sin(kTwoPi * t / period_s + phase);
}

}  // namespace

Pose lap_walk_pose(size_t i, double rate_hz) {
  const double t = static_cast<double>(i) / rate_hz;
  double k;
  const double walking = 1.0 - stop_share(nearest_stop_offset(t, &k));
  const double theta = walk_theta(walking_time(t));

  // The loop: semi-axes and centre drift with theta (0.61, 0.79, 0.37, 0.53 cycles a lap).
  const double a = kSemiXM + 0.06 * std::sin(0.61 * theta + 0.2);
  const double b = kSemiYM + 0.05 * std::sin(0.79 * theta + 2.3);
  const double cx = kCentreXM + 0.05 * std::sin(0.37 * theta + 0.4);
  const double cy = kCentreYM + 0.04 * std::sin(0.53 * theta + 1.1);
  // Fast jitter: sub-millimetre, a tenth of a degree, 5-7 Hz.
  const Eigen::Vector3d eye(
      cx + a * std::cos(theta) + 0.0005 * wave(t, 1.0 / 6.1, 0.0),
      cy + b * std::sin(theta) + 0.0005 * wave(t, 1.0 / 5.5, 1.3),
      1.4 + 0.04 * wave(t, 7.3, 0.3) + 0.005 * walking * wave(t, 1.0 / 1.8, 0.0) +
          0.0005 * wave(t, 1.0 / 5.7, 0.9));
  const double yaw = theta + 6.0 * kDeg * wave(t, 8.9, 0.2) + 0.1 * kDeg * wave(t, 1.0 / 5.3, 0.3);
  const double pitch = -18.0 * kDeg + 4.0 * kDeg * wave(t, 6.1, 0.5) +
                       0.7 * kDeg * wave(t, 2.3, 2.1) + 0.08 * kDeg * wave(t, 1.0 / 4.9, 0.0);
  const double roll = 2.5 * kDeg * wave(t, 5.2, 1.3) + 0.4 * kDeg * wave(t, 1.7, 0.4) +
                      0.08 * kDeg * wave(t, 1.0 / 6.3, 1.0);
  const Eigen::Vector3d forward(std::cos(yaw) * std::cos(pitch), std::sin(yaw) * std::cos(pitch),
                                std::sin(pitch));
  Pose T = look_at(eye, eye + forward);
  T.linear() = T.linear() * Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  return T;
}

}  // namespace depthfuse::synthetic::lap_rooms
