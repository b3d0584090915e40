// Sequences: frame fields, determinism by seed, pose perturbation statistics, and trajectories that
// keep the camera in free space with depths in the sensor's range.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <set>
#include <vector>

#include "depthfuse/synthetic/synthetic_sequence.hpp"
#include "depthfuse/synthetic/trajectory.hpp"

namespace depthfuse::synthetic {
namespace {

using Eigen::Vector3d;
constexpr double kPi = 3.14159265358979323846;

SyntheticSequence make(SyntheticConfig c) {
  auto s = SyntheticSequence::create(c);
  EXPECT_TRUE(s.is_ok()) << s.status().to_string();
  return std::move(s).value();
}

SyntheticConfig config(SceneKind kind, int frames, uint64_t seed = 1) {
  SyntheticConfig c;
  c.scene = kind;
  c.frames = frames;
  c.seed = seed;
  return c;
}

double angle_deg(const Eigen::Matrix3d& R) { return Eigen::AngleAxisd(R).angle() * 180.0 / kPi; }

TEST(Sequence, FramesCarryTheirMetadata) {
  SyntheticConfig c = config(SceneKind::kCorner, 10);
  c.rate_hz = 15.0;
  const SyntheticSequence seq = make(c);
  ASSERT_EQ(seq.size(), 10u);
  const Frame f = seq.render(3);
  EXPECT_EQ(f.utime, 200000);  // 3 / 15 Hz
  EXPECT_EQ(f.sequence, 3u);
  EXPECT_EQ(f.sensor_serial, "synthetic");
  EXPECT_EQ(f.intrinsics.width, 512);
  EXPECT_EQ(f.intrinsics.fx, 365.0);
  EXPECT_EQ(f.intrinsics.cy, 211.5);
  ASSERT_TRUE(f.T_world_cam_hint.has_value());
  EXPECT_TRUE(f.T_world_cam_hint->isApprox(seq.T_world_cam_true(3), 0.0));  // no pose noise
  EXPECT_FALSE(f.color.empty());

  // render_into reuses a frame.
  Frame g = seq.render(4);
  seq.render_into(3, true, &g);
  EXPECT_EQ(g.depth.depth_m, f.depth.depth_m);
  EXPECT_EQ(g.sequence, 3u);
}

TEST(Sequence, SameSeedSameFramesOtherSeedOtherFrames) {
  for (SceneKind kind : {SceneKind::kCorner, SceneKind::kRoom}) {
    SyntheticConfig c = config(kind, 20, 77);
    c.pose_noise_m = 0.01;
    c.pose_noise_deg = 0.5;
    const SyntheticSequence a = make(c), b = make(c);
    c.seed = 78;
    const SyntheticSequence other = make(c);
    for (size_t i : {size_t{0}, size_t{13}}) {
      const Frame fa = a.render(i), fb = b.render(i), fo = other.render(i);
      EXPECT_EQ(fa.depth.depth_m, fb.depth.depth_m);
      EXPECT_EQ(fa.color.rgb, fb.color.rgb);
      EXPECT_TRUE(fa.T_world_cam_hint->isApprox(*fb.T_world_cam_hint, 0.0));
      EXPECT_NE(fa.depth.depth_m, fo.depth.depth_m);
      EXPECT_FALSE(fa.T_world_cam_hint->isApprox(*fo.T_world_cam_hint, 1e-9));
      // The trajectory itself does not depend on the seed.
      EXPECT_TRUE(a.T_world_cam_true(i).isApprox(other.T_world_cam_true(i), 0.0));
    }
  }
}

TEST(Sequence, PosePerturbationFollowsTheRequestedStatistics) {
  SyntheticConfig c = config(SceneKind::kRooms, 4000, 5);
  c.pose_noise_m = 0.02;
  c.pose_noise_deg = 1.5;
  const SyntheticSequence seq = make(c);
  Vector3d sum = Vector3d::Zero(), sum2 = Vector3d::Zero(), axis_sum = Vector3d::Zero();
  double angle2 = 0;
  const size_t n = seq.size();
  for (size_t i = 0; i < n; ++i) {
    const Pose T = seq.T_world_cam_true(i), P = seq.T_world_cam_perturbed(i);
    const Vector3d dt = P.translation() - T.translation();
    sum += dt;
    sum2 += dt.cwiseAbs2();
    const Eigen::AngleAxisd aa(T.linear().transpose() * P.linear());
    angle2 += std::pow(aa.angle() * 180.0 / kPi, 2);
    axis_sum += aa.axis();
    // Deterministic: asking again gives the same pose.
    ASSERT_TRUE(seq.T_world_cam_perturbed(i).isApprox(P, 0.0));
  }
  for (int k = 0; k < 3; ++k) {
    const double sd = std::sqrt(sum2[k] / n);
    EXPECT_NEAR(sd, c.pose_noise_m, 0.05 * c.pose_noise_m) << "axis " << k;
    EXPECT_NEAR(sum[k] / n, 0.0, 0.1 * c.pose_noise_m) << "axis " << k;
  }
  EXPECT_NEAR(std::sqrt(angle2 / n), c.pose_noise_deg, 0.05 * c.pose_noise_deg);
  EXPECT_LT(axis_sum.norm() / n, 0.1);  // random axes, no preferred direction

  // No noise: the perturbed pose is the true pose, exactly.
  const SyntheticSequence clean = make(config(SceneKind::kRooms, 100, 5));
  for (size_t i = 0; i < 100; i += 7)
    EXPECT_TRUE(clean.T_world_cam_perturbed(i).isApprox(clean.T_world_cam_true(i), 0.0));
}

TEST(Trajectory, CameraFrameConvention) {
  const Pose T = look_at(Vector3d(0, 0, 1), Vector3d(0, 5, 1));                // looking north
  EXPECT_TRUE((T.linear() * Vector3d::UnitZ()).isApprox(Vector3d(0, 1, 0)));   // z forward
  EXPECT_TRUE((T.linear() * Vector3d::UnitX()).isApprox(Vector3d(1, 0, 0)));   // x right (east)
  EXPECT_TRUE((T.linear() * Vector3d::UnitY()).isApprox(Vector3d(0, 0, -1)));  // y down
  EXPECT_NEAR(T.linear().determinant(), 1.0, 1e-12);
}

TEST(Trajectory, CornerArcLooksIntoTheCornerWithOverlap) {
  const SyntheticSequence seq = make(config(SceneKind::kCorner, 60));
  double total_turn = 0;
  for (size_t i = 0; i < seq.size(); ++i) {
    const Pose T = seq.T_world_cam_true(i);
    const Vector3d eye = T.translation();
    const double axis_distance = eye.head<2>().norm();
    EXPECT_GE(axis_distance, 1.2);
    EXPECT_LE(axis_distance, 2.5);
    const Vector3d to_corner = (Vector3d(0, 0, 0.5) - eye).normalized();
    EXPECT_GT((T.linear() * Vector3d::UnitZ()).dot(to_corner), 0.95) << "frame " << i;
    if (i > 0) {
      const Pose P = seq.T_world_cam_true(i - 1);
      EXPECT_LT((eye - P.translation()).norm(), 0.1);
      const double turn = angle_deg(P.linear().transpose() * T.linear());
      EXPECT_LT(turn, 3.0);
      total_turn += turn;
    }
  }
  // About a 90 degree sweep around the corner.
  const Vector3d first = seq.T_world_cam_true(0).translation(),
                 last = seq.T_world_cam_true(59).translation();
  const double sweep =
      std::acos((first - Vector3d(0.6, 0.6, first.z()))
                    .head<2>()
                    .normalized()
                    .dot((last - Vector3d(0.6, 0.6, last.z())).head<2>().normalized())) *
      180 / kPi;
  EXPECT_NEAR(sweep, 90.0, 1.0);
  EXPECT_GT(total_turn, 60.0);
}

TEST(Trajectory, CamerasStayInFreeSpace) {
  // room: a closed loop, well away from every surface.
  const SyntheticSequence room = make(config(SceneKind::kRoom, 120));
  for (size_t i = 0; i < room.size(); ++i)
    EXPECT_GT(room.scene().distance_m(room.T_world_cam_true(i).translation()), 0.7)
        << "frame " << i;
  EXPECT_LT(
      (room.T_world_cam_true(119).translation() - room.T_world_cam_true(0).translation()).norm(),
      0.1);

  // rooms: 20 minutes at 30 Hz, sampled every 5 s; never near a wall or a box, every room visited,
  // and rooms come back (the walk goes round the tour several times).
  const SyntheticSequence rooms = make(config(SceneKind::kRooms, 36000));
  std::set<int> visited;
  std::vector<int> room_at;
  double min_clearance = 1e9;
  for (size_t i = 0; i < rooms.size(); i += 150) {
    const Vector3d eye = rooms.T_world_cam_true(i).translation();
    min_clearance = std::min(min_clearance, rooms.scene().distance_m(eye));
    const int r = static_cast<int>(eye.x() / 5) + 4 * static_cast<int>(eye.y() / 5);
    visited.insert(r);
    room_at.push_back(r);
  }
  EXPECT_GT(min_clearance, 0.5);
  EXPECT_EQ(visited.size(), 16u);
  const double tour_s = Trajectory::rooms_tour_length_m() / 0.5;
  EXPECT_GT(1200.0 / tour_s, 5.0);  // laps in 20 minutes
  // Consecutive frames overlap: small steps in position and orientation.
  for (size_t i = 1000; i < 1300; ++i) {
    const Pose a = rooms.T_world_cam_true(i - 1), b = rooms.T_world_cam_true(i);
    EXPECT_LT((b.translation() - a.translation()).norm(), 0.03);
    EXPECT_LT(angle_deg(a.linear().transpose() * b.linear()), 2.0);
  }
}

// Depths of the trajectories fall mostly within the Kinect's 0.5-4.5 m.
TEST(Trajectory, DepthsMostlyWithinTheSensorRange) {
  struct Case {
    SceneKind kind;
    int frames;
    double min_valid;
  };
  for (const Case& k : {Case{SceneKind::kCorner, 60, 0.95}, Case{SceneKind::kRoom, 60, 0.95},
                        Case{SceneKind::kRooms, 36000, 0.7}}) {
    SyntheticConfig c = config(k.kind, k.frames);
    c.min_depth_m = 1e-3;
    c.max_depth_m = 1e3;
    c.noise.enabled = false;
    const SyntheticSequence seq = make(c);
    size_t in_range = 0, total = 0;
    for (size_t s = 0; s < 6; ++s) {
      const Frame f = seq.render(s * (seq.size() - 1) / 5, false);
      for (float z : f.depth.depth_m) {
        ++total;
        in_range += z >= 0.5f && z <= 4.5f;
      }
    }
    EXPECT_GT(static_cast<double>(in_range) / total, k.min_valid) << to_string(k.kind);
  }
}

TEST(Sequence, InvalidConfigsAreRejected) {
  auto expect_error = [](SyntheticConfig c, const std::string& needle) {
    auto s = SyntheticSequence::create(c);
    ASSERT_FALSE(s.is_ok());
    EXPECT_EQ(s.status().code(), StatusCode::kInvalidArgument);
    EXPECT_NE(s.status().message().find(needle), std::string::npos) << s.status().message();
  };
  SyntheticConfig c;
  c.frames = 0;
  expect_error(c, "frames");
  c = SyntheticConfig();
  c.pose_noise_m = -0.1;
  expect_error(c, "pose_noise_m");
  c = SyntheticConfig();
  c.rate_hz = 0;
  expect_error(c, "rate_hz");
  c = SyntheticConfig();
  c.intrinsics.fx = 0;
  expect_error(c, "intrinsics");
  c = SyntheticConfig();
  c.min_depth_m = 5;
  expect_error(c, "min_depth_m");
}

TEST(Sequence, GeneratorTomlRoundTrip) {
  SyntheticConfig c = config(SceneKind::kRoom, 123, 0xffffffffffffff00ull);  // beyond int64
  c.pose_noise_m = 0.015;
  c.pose_noise_deg = 0.7;
  c.noise.mpi_max_bias_m = 0.012;
  c.noise.outlier_enabled = false;
  c.rate_hz = 29.97;
  auto back = parse_synthetic_config_toml(synthetic_config_to_toml(c));
  ASSERT_TRUE(back.is_ok()) << back.status().to_string();
  EXPECT_EQ(back->scene, c.scene);
  EXPECT_EQ(back->frames, 123);
  EXPECT_EQ(back->seed, c.seed);
  EXPECT_EQ(back->pose_noise_m, c.pose_noise_m);
  EXPECT_EQ(back->pose_noise_deg, c.pose_noise_deg);
  EXPECT_EQ(back->rate_hz, c.rate_hz);
  EXPECT_EQ(back->noise.mpi_max_bias_m, c.noise.mpi_max_bias_m);
  EXPECT_FALSE(back->noise.outlier_enabled);
  EXPECT_EQ(synthetic_config_to_toml(*back), synthetic_config_to_toml(c));

  auto bad = parse_synthetic_config_toml("[generator]\nscene = \"room\"\nfrmes = 3\n", "g.toml");
  ASSERT_FALSE(bad.is_ok());
  EXPECT_NE(bad.status().message().find("g.toml:3: generator.frmes: unknown key"), std::string::npos)
      << bad.status().message();
  EXPECT_FALSE(parse_synthetic_config_toml("[scene]\n").is_ok());
  for (const char* seed : {"-3", "\"12x\"", "\"\"", "1.5"}) {
    auto bad_seed = parse_synthetic_config_toml(std::string("[generator]\nseed = ") + seed + "\n");
    ASSERT_FALSE(bad_seed.is_ok()) << seed;
    EXPECT_NE(bad_seed.status().message().find("generator.seed"), std::string::npos)
        << bad_seed.status().message();
  }
  auto bad_scene = parse_synthetic_config_toml("[generator]\nscene = \"kitchen\"\n", "g.toml");
  ASSERT_FALSE(bad_scene.is_ok());
  EXPECT_NE(bad_scene.status().message().find("g.toml:2: generator.scene: unknown synthetic scene"),
            std::string::npos)
      << bad_scene.status().message();
}

}  // namespace
}  // namespace depthfuse::synthetic
