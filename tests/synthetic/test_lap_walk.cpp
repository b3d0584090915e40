// The furnished and plain rooms and their handheld walk of laps: free space, surfaces in the
// sensor's range, the laps and the return past the start, a handheld's pace, views of the sofa
// that say nothing along it, determinism by seed.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "depthfuse/synthetic/synthetic_sequence.hpp"
#include "depthfuse/synthetic/synthetic_source.hpp"
#include "synthetic_test_util.hpp"

namespace depthfuse::synthetic {
namespace {

using Eigen::Vector3d;
constexpr double kPi = 3.14159265358979323846;
const Vector3d kMiddle(2.5, 2.3, 0.0);  // the middle of the walk's loop

SyntheticSequence make(SceneKind kind, int frames, uint64_t seed = 1) {
  SyntheticConfig c;
  c.scene = kind;
  c.frames = frames;
  c.seed = seed;
  auto s = SyntheticSequence::create(c);
  EXPECT_TRUE(s.is_ok()) << s.status().to_string();
  return std::move(s).value();
}

double angle_deg(const Eigen::Matrix3d& R) { return Eigen::AngleAxisd(R).angle() * 180.0 / kPi; }

// The camera's bearing from the middle of the room, unwrapped over frames [0, n) taken every
// `step`: how far round the room the walk has gone.
std::vector<double> unwrapped_bearing(const SyntheticSequence& seq, size_t n, size_t step) {
  std::vector<double> out;
  double last = 0.0, offset = 0.0;
  for (size_t i = 0; i < n; i += step) {
    const Vector3d d = seq.T_world_cam_true(i).translation() - kMiddle;
    const double a = std::atan2(d.y(), d.x());
    if (!out.empty()) {
      if (a - last > kPi) offset -= 2 * kPi;
      if (a - last < -kPi) offset += 2 * kPi;
    }
    last = a;
    out.push_back(a + offset);
  }
  return out;
}

const Primitive& find(const Scene& scene, const std::string& name) {
  for (const Primitive& p : scene.primitives())
    if (p.name == name) return p;
  ADD_FAILURE() << "no primitive " << name;
  return scene.primitives().front();
}

// The share of a frame's surface normals (sampled pixels, exact normals from the scene) along
// `axis`, over the largest share along any direction: the translation information a
// point-to-plane ICP gets along `axis`, relative to its best direction.
double normal_share_along(const SyntheticSequence& seq, size_t i, const Vector3d& axis) {
  const Pose T = seq.T_world_cam_true(i);
  const CameraIntrinsics& K = seq.config().intrinsics;
  const Frame f = seq.render(i, false);
  Eigen::Matrix3d M = Eigen::Matrix3d::Zero();
  for (int v = 0; v < K.height; v += 2)
    for (int u = 0; u < K.width; u += 2) {
      if (f.depth.at(u, v) <= 0) continue;
      const Vector3d d = T.linear() * Vector3d((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
      RayHit hit;
      if (!seq.scene().raycast(T.translation(), d, 10.0, &hit)) continue;
      M += hit.normal_w * hit.normal_w.transpose();
    }
  const double largest = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(M).eigenvalues()(2);
  return axis.dot(M * axis) / largest;
}

TEST(LapWalk, StaysInFreeSpaceWithTheSurfacesInRange) {
  for (SceneKind kind : {SceneKind::kFurnished, SceneKind::kPlain}) {
    for (uint64_t seed : {1u, 2u}) {
      const SyntheticSequence seq = make(kind, 1200, seed);
      double clearance = 1e9;
      for (size_t i = 0; i < seq.size(); i += 5) {
        const Vector3d eye = seq.T_world_cam_true(i).translation();
        ASSERT_TRUE(eye.x() > 0 && eye.x() < 5 && eye.y() > 0 && eye.y() < 4 && eye.z() > 0 &&
                    eye.z() < 2.6)
            << "frame " << i << " outside the room";
        clearance = std::min(clearance, seq.scene().distance_m(eye));
      }
      EXPECT_GT(clearance, 0.5) << to_string(kind) << " seed " << seed;
    }
    // Every pixel sees a surface (a closed room) and nearly all within 0.5-4.5 m; none nearer.
    SyntheticConfig c;
    c.scene = kind;
    c.frames = 1200;
    c.min_depth_m = 1e-3;
    c.max_depth_m = 1e3;
    auto wide = SyntheticSequence::create(c);
    ASSERT_TRUE(wide.is_ok());
    for (size_t i = 0; i < 1200; i += 97) {
      const Frame f = wide->render(i, false);
      size_t in_range = 0, near = 0, none = 0;
      for (float z : f.depth.depth_m) {
        none += z <= 0.0f;
        near += z > 0.0f && z < 0.5f;
        in_range += z >= 0.5f && z <= 4.5f;
      }
      EXPECT_EQ(none, 0u) << to_string(kind) << " frame " << i;
      EXPECT_EQ(near, 0u) << to_string(kind) << " frame " << i;
      EXPECT_GT(static_cast<double>(in_range) / f.depth.depth_m.size(), 0.99)
          << to_string(kind) << " frame " << i;
    }
  }
}

TEST(LapWalk, MakesTwoLapsThatDifferAndComesBackPastItsStart) {
  const SyntheticSequence seq = make(SceneKind::kFurnished, 1200);
  EXPECT_EQ(default_frames(SceneKind::kFurnished), 1200);
  const std::vector<double> bearing = unwrapped_bearing(seq, seq.size(), 1);
  const double laps = (bearing.back() - bearing.front()) / (2 * kPi);
  EXPECT_GT(laps, 2.03);  // two laps, and on past the start
  EXPECT_LT(laps, 2.4);
  // Back where it began, near enough for a loop closure: in the second lap's end, a frame within
  // 10 cm and 10 degrees of the first one.
  const Pose first = seq.T_world_cam_true(0);
  double best_m = 1e9, best_deg = 1e9;
  for (size_t i = 1000; i < seq.size(); ++i) {
    const Pose T = seq.T_world_cam_true(i);
    const double m = (T.translation() - first.translation()).norm();
    if (m < best_m) {
      best_m = m;
      best_deg = angle_deg(first.linear().transpose() * T.linear());
    }
  }
  EXPECT_LT(best_m, 0.1);
  EXPECT_LT(best_deg, 15.0);
  // Not a perfect repeat: at the same bearing the two laps are centimetres apart.
  size_t j = 0;
  double largest_m = 0.0;
  for (size_t i = 0; i < 500; i += 10) {
    while (j + 1 < bearing.size() && bearing[j] < bearing[i] + 2 * kPi) ++j;
    largest_m = std::max(largest_m, (seq.T_world_cam_true(j).translation() -
                                     seq.T_world_cam_true(i).translation())
                                        .norm());
  }
  EXPECT_GT(largest_m, 0.03);
  // A 20-minute scan goes round many times, at the same pace.
  const SyntheticSequence long_scan = make(SceneKind::kFurnished, 36000);
  const std::vector<double> long_bearing = unwrapped_bearing(long_scan, long_scan.size(), 10);
  EXPECT_GT((long_bearing.back() - long_bearing.front()) / (2 * kPi), 55.0);
}

TEST(LapWalk, MovesAtAHandheldPaceWithAStop) {
  const SyntheticSequence seq = make(SceneKind::kFurnished, 1200);
  std::vector<double> step_mm, turn_deg;
  for (size_t i = 1; i < seq.size(); ++i) {
    const Pose a = seq.T_world_cam_true(i - 1), b = seq.T_world_cam_true(i);
    step_mm.push_back(1e3 * (b.translation() - a.translation()).norm());
    turn_deg.push_back(angle_deg(a.linear().transpose() * b.linear()));
  }
  auto mean = [](const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += x;
    return s / v.size();
  };
  EXPECT_GT(mean(step_mm), 5.5);
  EXPECT_LT(mean(step_mm), 8.5);
  EXPECT_GT(mean(turn_deg), 0.45);
  EXPECT_LT(mean(turn_deg), 0.8);
  EXPECT_LT(*std::max_element(step_mm.begin(), step_mm.end()), 16.0);
  EXPECT_LT(*std::max_element(turn_deg.begin(), turn_deg.end()), 1.6);
  // The speed varies, down to a stop (several frames in a row under 1.5 mm).
  std::vector<double> sorted = step_mm;
  std::sort(sorted.begin(), sorted.end());
  EXPECT_GT(sorted[sorted.size() * 9 / 10], 2.0 * sorted[sorted.size() / 10]);
  size_t run = 0, longest = 0;
  for (double s : step_mm) {
    run = s < 1.5 ? run + 1 : 0;
    longest = std::max(longest, run);
  }
  EXPECT_GE(longest, 5u);
  // A handheld's sway: height and roll are not constant.
  double z_lo = 1e9, z_hi = -1e9;
  for (size_t i = 0; i < seq.size(); i += 3) {
    const double z = seq.T_world_cam_true(i).translation().z();
    z_lo = std::min(z_lo, z);
    z_hi = std::max(z_hi, z);
  }
  EXPECT_GT(z_hi - z_lo, 0.05);
}

// The sofa's long axis is x. While the camera passes it, with the sofa alone in view, nothing
// seen has a normal along x (below 0.3 % of the strongest direction, the tracker's
// tracking_degenerate_ratio, for half a second and more): the depth cannot tell how far the
// camera slid along the sofa. Views
// of the bookshelf's wall (shelves, books, a picture) say plainly where the camera is along that
// wall: the measure tells the two apart.
TEST(LapWalk, ViewsOfTheSofaSayNothingAlongIt) {
  const SyntheticSequence seq = make(SceneKind::kFurnished, 1200);
  auto heading_deg = [&](size_t i) {
    const Vector3d forward = seq.T_world_cam_true(i).linear().col(2);
    return std::atan2(forward.y(), forward.x()) * 180.0 / kPi;
  };
  // Lap 1, every 2nd frame while the camera faces north (the sofa) within 25 degrees.
  size_t run = 0, longest = 0, facing = 0;
  for (size_t i = 0; i < 700; i += 2) {
    if (std::fabs(heading_deg(i) - 90.0) > 25.0) continue;
    ++facing;
    const double share = normal_share_along(seq, i, Vector3d::UnitX());
    run = share < 0.003 ? run + 1 : 0;
    longest = std::max(longest, run);
  }
  EXPECT_GT(facing, 20u);
  EXPECT_GE(2 * longest, 14u) << "frames in a row with (almost) nothing along the sofa";
  size_t west = 0;
  for (size_t i = 0; i < 700; i += 10) {
    if (std::fabs(std::fabs(heading_deg(i)) - 180.0) > 15.0) continue;
    ++west;
    EXPECT_GT(normal_share_along(seq, i, Vector3d::UnitY()), 0.02) << "frame " << i;
  }
  EXPECT_GT(west, 2u);
}

// The rooms are scanned with the Kinect V2's time-of-flight errors unless told otherwise: axial
// noise, dropouts, and the multipath bias that lengthens the range near concave edges (the room's
// corners, where furniture meets the floor).
TEST(LapWalk, FramesHaveTheKinectV2sErrorsByDefault) {
  const SyntheticSequence seq = make(SceneKind::kPlain, 1200);
  const NoiseConfig& n = seq.config().noise;
  EXPECT_TRUE(n.enabled && n.axial_enabled && n.flying_enabled && n.mpi_enabled &&
              n.dropout_enabled && n.outlier_enabled);
  const CameraIntrinsics& K = seq.config().intrinsics;
  double near_edge_sum = 0.0, open_sum = 0.0;
  size_t near_edge = 0, open = 0, dropped = 0, valid = 0;
  for (size_t i : {size_t{40}, size_t{500}}) {  // views with the floor and a corner of the room
    const Frame noisy = seq.render(i, true), exact = seq.render(i, false);
    const Pose T = seq.T_world_cam_true(i);
    for (int v = 0; v < K.height; v += 2)
      for (int u = 0; u < K.width; u += 2) {
        const double z = exact.depth.at(u, v), zn = noisy.depth.at(u, v);
        if (z <= 0) continue;
        ++valid;
        if (zn <= 0) {
          ++dropped;
          continue;
        }
        const Vector3d d = T.linear() * Vector3d((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
        RayHit hit;
        ASSERT_TRUE(seq.scene().raycast(T.translation(), d, 10.0, &hit));
        const double edge_m = seq.scene().concave_edge_distance_m(
            T.translation() + hit.t * d, hit.normal_w, hit.primitive, hit.face, 1.0);
        if (edge_m < 0.02) near_edge_sum += zn - z, ++near_edge;
        if (edge_m > 0.3) open_sum += zn - z, ++open;
      }
  }
  EXPECT_GT(static_cast<double>(dropped) / valid, 0.001);
  ASSERT_GT(near_edge, 100u);
  ASSERT_GT(open, 1000u);
  EXPECT_GT(near_edge_sum / near_edge, 0.003);    // lengthened by multipath
  EXPECT_LT(std::fabs(open_sum / open), 0.0015);  // unbiased away from edges
}

TEST(LapWalk, TheSeedMovesTheFurnitureNotTheWalk) {
  const SyntheticSequence a = make(SceneKind::kFurnished, 1200, 5);
  const SyntheticSequence b = make(SceneKind::kFurnished, 1200, 5);
  const SyntheticSequence c = make(SceneKind::kFurnished, 1200, 6);
  EXPECT_EQ(a.scene().to_toml(), b.scene().to_toml());
  EXPECT_NE(a.scene().to_toml(), c.scene().to_toml());
  for (size_t i : {size_t{0}, size_t{333}, size_t{1199}}) {
    EXPECT_TRUE(a.T_world_cam_true(i).isApprox(c.T_world_cam_true(i), 0.0));
    const Frame fa = a.render(i), fb = b.render(i);
    EXPECT_EQ(fa.depth.depth_m, fb.depth.depth_m) << "frame " << i;
    EXPECT_EQ(fa.color.rgb, fb.color.rgb) << "frame " << i;
  }
  EXPECT_NE(make(SceneKind::kPlain, 10, 5).scene().to_toml(),
            make(SceneKind::kPlain, 10, 6).scene().to_toml());
  // Every surface of the scene survives its TOML (the colour texture too).
  auto back = Scene::parse_toml(a.scene().to_toml());
  ASSERT_TRUE(back.is_ok()) << back.status().to_string();
  EXPECT_EQ(back->to_toml(), a.scene().to_toml());
  EXPECT_EQ(find(*back, "wall_north").checker_m, 0.0);
}

// The capture daemon's spec: two laps unless told, and frames without hints on request.
TEST(LapWalk, SpecDefaultsToTwoLapsAndCanLeaveTheHintsOut) {
  auto spec = parse_synthetic_spec("furnished?hints=0&seed=3");
  ASSERT_TRUE(spec.is_ok()) << spec.status().to_string();
  EXPECT_EQ(spec->frames, 1200);
  EXPECT_FALSE(spec->pose_hints);
  EXPECT_EQ(parse_synthetic_spec("plain?frames=90")->frames, 90);
  EXPECT_FALSE(parse_synthetic_spec("plain?hints=2").is_ok());
  auto source = open_synthetic_source("furnished?hints=0&frames=2", AppConfig());
  ASSERT_TRUE(source.is_ok()) << source.status().to_string();
  auto frame = (*source)->next();
  ASSERT_TRUE(frame.is_ok());
  EXPECT_FALSE(frame->T_world_cam_hint.has_value());
  EXPECT_NE((*source)->describe().find("no pose hints"), std::string::npos);
  auto hinted = open_synthetic_source("plain?frames=2", AppConfig());
  ASSERT_TRUE(hinted.is_ok());
  EXPECT_TRUE((*hinted)->next()->T_world_cam_hint.has_value());
}

}  // namespace
}  // namespace depthfuse::synthetic
