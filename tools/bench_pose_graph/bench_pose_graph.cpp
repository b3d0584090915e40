// The pose graph of a handheld scan: two laps around a room, odometry with tracking's noise and a
// stretch along a sofa each lap where the depth did not see the motion along the walk (2 cm lost a
// keyframe, the motion model's 5 cm the only information there), a loop edge to the first lap every
// 20 keyframes of the second, and 0, 1 or 5 wrong closures (1 m off) that must be rejected.
// rms_after_mm is the same with and without them when the map is not bent.
#include <benchmark/benchmark.h>

#include <cmath>
#include <random>

#include "depthfuse/pose_graph.hpp"

using namespace depthfuse;

namespace {

// Rotation vector, then translation.
Pose pose_from(const Vector6d& xi) {
  Pose T = Pose::Identity();
  const Eigen::Vector3d w = xi.head<3>();
  if (w.norm() > 0) T.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
  T.translation() = xi.tail<3>();
  return T;
}

Vector6d vec6(double rx, double ry, double rz, double tx, double ty, double tz) {
  Vector6d v;
  v << rx, ry, rz, tx, ty, tz;
  return v;
}

struct Scan {
  std::vector<Pose> T_world_truth;
  std::vector<Pose> T_world_initial;  // the odometry's
  std::vector<PoseGraphEdge> edges;
  size_t loops = 0;
};

Scan make_scan(uint32_t nodes, uint32_t wrong_loops) {
  std::mt19937 rng(11);
  std::normal_distribution<double> unit;
  const double sigma_m = 0.001, sigma_rad = 0.02 * M_PI / 180;  // per keyframe
  const auto noise = [&] {
    return vec6(sigma_rad * unit(rng), sigma_rad * unit(rng), sigma_rad * unit(rng),
                sigma_m * unit(rng), sigma_m * unit(rng), sigma_m * unit(rng));
  };
  const Matrix6d information = vec6(1, 1, 1, 0, 0, 0).asDiagonal() * (1 / (sigma_rad * sigma_rad)) +
                               vec6(0, 0, 0, 1, 1, 1).asDiagonal() * (1 / (sigma_m * sigma_m));
  Scan s;
  // Two laps of a 4 x 3 m ellipse at 1.2-1.4 m height, looking out at the walls: the camera's x
  // along the walk, y down.
  for (uint32_t i = 0; i < nodes; ++i) {
    const double a = 4 * M_PI * i / nodes;
    const Eigen::Vector3d z = Eigen::Vector3d(std::cos(a), std::sin(a), 0.1 * std::sin(5 * a)).normalized();
    const Eigen::Vector3d x = Eigen::Vector3d(0, 0, -1).cross(z).normalized();
    Pose T = Pose::Identity();
    T.linear() << x, z.cross(x), z;
    T.translation() = Eigen::Vector3d(2.0 * std::cos(a), 1.5 * std::sin(a), 1.3 + 0.1 * std::sin(7 * a));
    s.T_world_truth.push_back(T);
  }
  s.T_world_initial.push_back(s.T_world_truth[0]);
  for (uint32_t i = 0; i + 1 < nodes; ++i) {
    PoseGraphEdge e;
    e.from = i;
    e.to = i + 1;
    e.T_from_to = s.T_world_truth[i].inverse() * s.T_world_truth[i + 1] * pose_from(noise());
    e.information = information;
    const uint32_t in_lap = i % (nodes / 2);
    if (in_lap >= nodes / 8 && in_lap < nodes / 8 + nodes / 20) {  // along the sofa
      e.T_from_to = e.T_from_to * pose_from(vec6(0, 0, 0, -2.0 / nodes, 0, 0));
      e.information(3, 3) = 1 / (0.05 * 0.05);
    }
    s.T_world_initial.push_back(s.T_world_initial.back() * e.T_from_to);
    s.edges.push_back(e);
  }
  for (uint32_t i = nodes / 2; i < nodes; i += 20) {
    PoseGraphEdge e;
    e.kind = PoseGraphEdge::Kind::kLoop;
    e.from = i - nodes / 2;
    e.to = i;
    e.T_from_to = s.T_world_truth[e.from].inverse() * s.T_world_truth[i] * pose_from(noise());
    e.information = information;
    s.edges.push_back(e);
  }
  // Each wrong closure beside a right one, from a keyframe 7 further on, 1 m off along x, y or z.
  const size_t right_loops = s.edges.size() - (nodes - 1);
  for (uint32_t k = 0; k < wrong_loops && k < right_loops; ++k) {
    PoseGraphEdge e = s.edges[nodes - 1 + k * right_loops / wrong_loops];
    e.from += 7;
    Vector6d off = Vector6d::Zero();
    off(3 + k % 3) = 1.0;
    e.T_from_to = e.T_from_to * pose_from(off);
    s.edges.push_back(e);
  }
  s.loops = s.edges.size() - (nodes - 1);
  return s;
}

double rms_m(const std::vector<Pose>& a, const std::vector<Pose>& b) {
  double sum = 0;
  for (size_t i = 0; i < a.size(); ++i) sum += (a[i].translation() - b[i].translation()).squaredNorm();
  return std::sqrt(sum / a.size());
}

void BM_PoseGraph(benchmark::State& state) {
  const Scan s = make_scan(static_cast<uint32_t>(state.range(0)), static_cast<uint32_t>(state.range(1)));
  PoseGraphResult last;
  for (auto _ : state) {
    Result<PoseGraphResult> r = optimise_pose_graph(s.T_world_initial, s.edges);
    if (!r) {
      state.SkipWithError(r.status().to_string().c_str());
      return;
    }
    last = std::move(*r);
  }
  state.counters["loops"] = static_cast<double>(s.loops);
  state.counters["rejected"] = static_cast<double>(last.loops_rejected);
  state.counters["iterations"] = last.iterations;
  state.counters["rms_before_mm"] = 1e3 * rms_m(s.T_world_initial, s.T_world_truth);
  state.counters["rms_after_mm"] = 1e3 * rms_m(last.T_world_node, s.T_world_truth);
}

}  // namespace

// Arguments: keyframes, wrong closures.
BENCHMARK(BM_PoseGraph)
    ->ArgsProduct({{100, 300, 1000}, {0, 1, 5}})
    ->ArgNames({"nodes", "wrong"})
    ->Unit(benchmark::kMillisecond);
BENCHMARK_MAIN();
