// Rendering: exact depth against the analytic surfaces, and each effect of the noise model on its
// own against the model's own formula.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <thread>
#include <vector>

#include "depthfuse/synthetic/renderer.hpp"
#include "depthfuse/synthetic/synthetic_sequence.hpp"
#include "depthfuse/synthetic/trajectory.hpp"
#include "synthetic_test_util.hpp"

namespace depthfuse::synthetic {
namespace {

using Eigen::Vector3d;
using testing::backproject;
constexpr double kPi = 3.14159265358979323846;

SyntheticSequence make_sequence(SceneKind kind, int frames, NoiseConfig noise = NoiseConfig(),
                                uint64_t seed = 1) {
  SyntheticConfig c;
  c.scene = kind;
  c.frames = frames;
  c.noise = noise;
  c.seed = seed;
  auto s = SyntheticSequence::create(c);
  EXPECT_TRUE(s.is_ok()) << s.status().to_string();
  return std::move(s).value();
}

// A camera at the origin looking along +z (optical frame = world frame) at an unbounded plane
// through (0, 0, distance) whose normal is tilted by tilt_deg about the x axis.
DepthRenderer plane_renderer(double distance_m, double tilt_deg, const NoiseConfig& noise) {
  const double a = tilt_deg * kPi / 180.0;
  const Vector3d normal(0, std::sin(a), -std::cos(a));
  auto scene =
      Scene::create({Primitive::plane(Vector3d(0, 0, distance_m), normal, Vector3d::UnitX(),
                                      -INFINITY, INFINITY, -INFINITY, INFINITY, "wall")});
  EXPECT_TRUE(scene.is_ok());
  RendererConfig rc;
  rc.noise = noise;
  return DepthRenderer(std::make_shared<const Scene>(std::move(scene).value()), rc);
}

TEST(Render, ExactCornerFramesLieOnTheAnalyticPlanes) {
  const SyntheticSequence seq = make_sequence(SceneKind::kCorner, 60);
  const CameraIntrinsics& K = seq.config().intrinsics;
  for (size_t i : {size_t{0}, size_t{20}, size_t{41}, size_t{59}}) {
    const Frame f = seq.render(i, false);
    ASSERT_EQ(f.depth.width, 512);
    ASSERT_EQ(f.depth.height, 424);
    const Pose T = seq.T_world_cam_true(i);
    size_t valid = 0;
    double worst = 0;
    for (int v = 0; v < K.height; ++v)
      for (int u = 0; u < K.width; ++u) {
        const double z = f.depth.at(u, v);
        if (z <= 0) continue;
        ++valid;
        worst = std::max(worst, seq.scene().distance_m(backproject(K, T, u, v, z)));
      }
    EXPECT_LT(worst, 1e-4) << "frame " << i;
    EXPECT_GT(valid, f.depth.depth_m.size() * 9 / 10) << "frame " << i;
  }
}

// The renderer culls primitives per tile; it must agree with a plain raycast at every pixel.
TEST(Render, ExactDepthMatchesRaycastInRoomScenes) {
  for (SceneKind kind : {SceneKind::kRoom, SceneKind::kRooms}) {
    const SyntheticSequence seq = make_sequence(kind, kind == SceneKind::kRooms ? 36000 : 60);
    const CameraIntrinsics& K = seq.config().intrinsics;
    for (size_t i : {size_t{3}, size_t{17}, size_t{4321}, size_t{35000}}) {
      if (i >= seq.size()) continue;
      const Frame f = seq.render(i, false);
      const Pose T = seq.T_world_cam_true(i);
      size_t mismatches = 0;
      for (int v = 0; v < K.height; v += 3)
        for (int u = 0; u < K.width; u += 3) {
          const Vector3d d = T.linear() * Vector3d((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
          double t = 0;
          double expected = 0;
          if (seq.scene().raycast(T.translation(), d, &t, nullptr) && t >= 0.5 && t <= 4.5)
            expected = t;
          if (std::fabs(f.depth.at(u, v) - expected) > 1e-5) ++mismatches;
        }
      EXPECT_EQ(mismatches, 0u) << to_string(kind) << " frame " << i;
    }
  }
}

// Axial noise: the residual's standard deviation follows Fankhauser et al. at 1 m and at 3 m.
TEST(Noise, AxialStdMatchesTheKinectV2Model) {
  NoiseConfig noise = NoiseConfig::none();
  noise.axial_enabled = true;
  const CameraIntrinsics K = CameraIntrinsics::kinect_v2();
  for (double distance : {1.0, 3.0}) {
    const DepthRenderer r = plane_renderer(distance, 0.0, noise);
    const double expected = fankhauser_axial_sigma_m(distance, 0.0, 1.0);
    double sum = 0, sum2 = 0, norm2 = 0;
    size_t n_center = 0, n_all = 0;
    for (uint64_t key : {11u, 12u}) {
      DepthImage depth;
      r.render(Pose::Identity(), key, true, &depth, nullptr);
      for (int v = 0; v < K.height; ++v)
        for (int u = 0; u < K.width; ++u) {
          const double z = depth.at(u, v);
          ASSERT_GT(z, 0.0);
          const double e = z - distance;
          const double x = (u - K.cx) / K.fx, y = (v - K.cy) / K.fy;
          const double theta = std::acos(1.0 / std::sqrt(1 + x * x + y * y));
          norm2 += std::pow(e / fankhauser_axial_sigma_m(distance, theta, 80 * kPi / 180), 2);
          ++n_all;
          if (theta < 10 * kPi / 180) {
            sum += e;
            sum2 += e * e;
            ++n_center;
          }
        }
    }
    ASSERT_GT(n_center, 20000u);
    const double mean = sum / n_center;
    const double sd = std::sqrt(sum2 / n_center - mean * mean);
    // Near the axis theta < 10 deg adds at most 0.1 * z^1.5 * 0.0145 mm: within the tolerance.
    EXPECT_NEAR(sd, expected, 0.03 * expected) << "at " << distance << " m";
    EXPECT_NEAR(mean, 0.0, 0.05 * expected);
    EXPECT_NEAR(std::sqrt(norm2 / n_all), 1.0, 0.02)
        << "normalised residual at " << distance << " m";
  }
  EXPECT_NEAR(fankhauser_axial_sigma_m(1.0, 0.0, 1.0), 1.3e-3, 1e-12);
  EXPECT_NEAR(fankhauser_axial_sigma_m(3.0, 0.0, 1.0), 2.7e-3, 1e-12);
  // The incidence term grows towards grazing angles.
  EXPECT_GT(fankhauser_axial_sigma_m(2.0, 1.2, 1.4), 2 * fankhauser_axial_sigma_m(2.0, 0.0, 1.4));
}

// Flying pixels appear only where the exact depth of the 3x3 neighbourhood jumps, between the
// nearest and the farthest depth there.
TEST(Noise, FlyingPixelsOnlyAtDepthEdges) {
  NoiseConfig noise = NoiseConfig::none();
  noise.flying_enabled = true;
  const SyntheticSequence seq = make_sequence(SceneKind::kRoom, 60, noise);
  size_t changed = 0, edge_pixels = 0;
  for (size_t i : {size_t{5}, size_t{25}}) {
    const Frame exact = seq.render(i, false);
    const Frame noisy = seq.render(i, true);
    const int W = exact.depth.width, H = exact.depth.height;
    for (int v = 0; v < H; ++v)
      for (int u = 0; u < W; ++u) {
        const float z0 = exact.depth.at(u, v);
        if (z0 <= 0) continue;
        double lo = z0, hi = z0;
        for (int dv = -1; dv <= 1; ++dv)
          for (int du = -1; du <= 1; ++du) {
            const int uu = u + du, vv = v + dv;
            if (uu < 0 || vv < 0 || uu >= W || vv >= H || exact.depth.at(uu, vv) <= 0) continue;
            lo = std::min(lo, double{exact.depth.at(uu, vv)});
            hi = std::max(hi, double{exact.depth.at(uu, vv)});
          }
        const bool edge =
            hi - lo > std::max(noise.flying_min_jump_m, noise.flying_min_jump_fraction * lo);
        edge_pixels += edge;
        const float z = noisy.depth.at(u, v);
        if (z == z0) continue;
        ++changed;
        ASSERT_TRUE(edge) << "pixel " << u << "," << v << " changed away from any depth edge";
        EXPECT_GE(z, lo - 1e-6);
        EXPECT_LE(z, hi + 1e-6);
      }
  }
  ASSERT_GT(edge_pixels, 500u);
  const double fraction = static_cast<double>(changed) / edge_pixels;
  EXPECT_NEAR(fraction, noise.flying_probability, 0.05);
}

// Multipath: a positive bias that follows the documented model of the distance to the concave
// edge; in the corner scene that distance is analytic.
TEST(Noise, MultipathBiasNearConcaveEdges) {
  NoiseConfig noise = NoiseConfig::none();
  noise.mpi_enabled = true;
  const SyntheticSequence seq = make_sequence(SceneKind::kCorner, 60, noise);
  const CameraIntrinsics& K = seq.config().intrinsics;
  double near_sum = 0, far_max = 0;
  size_t near_n = 0, far_n = 0;
  for (size_t i : {size_t{10}, size_t{45}}) {
    const Frame exact = seq.render(i, false);
    const Frame noisy = seq.render(i, true);
    const Pose T = seq.T_world_cam_true(i);
    for (int v = 0; v < K.height; ++v)
      for (int u = 0; u < K.width; ++u) {
        const double z0 = exact.depth.at(u, v);
        if (z0 <= 0) continue;
        const double bias = noisy.depth.at(u, v) - z0;
        ASSERT_GE(bias, -1e-6);
        const Vector3d p = backproject(K, T, u, v, z0);
        // On one of the three planes (one coordinate ~0) the edge distance is the smaller of the
        // other two coordinates.
        Vector3d a = p.cwiseAbs();
        int on = 0;
        a.minCoeff(&on);
        const double edge = std::min(a[(on + 1) % 3], a[(on + 2) % 3]);
        const double range = (p - T.translation()).norm();
        const double expected = mpi_bias_m(noise, edge) * z0 / range;
        EXPECT_NEAR(bias, expected, 2e-6) << "pixel " << u << "," << v;
        if (edge < 0.03) {
          near_sum += bias * range / z0;
          ++near_n;
        }
        if (edge > noise.mpi_range_m + 1e-3) {
          far_max = std::max(far_max, std::fabs(bias));
          ++far_n;
        }
      }
  }
  ASSERT_GT(near_n, 100u);
  ASSERT_GT(far_n, 10000u);
  EXPECT_GT(near_sum / near_n, 0.6 * noise.mpi_max_bias_m);  // several mm right at the edge
  EXPECT_LT(far_max, 1e-6);

  // In the room: the floor beside a box and the walls' corners are biased, the middle of the floor
  // is not.
  const SyntheticSequence room = make_sequence(SceneKind::kRoom, 60, noise);
  const Frame exact = room.render(30, false);
  const Frame noisy = room.render(30, true);
  size_t biased = 0;
  for (size_t k = 0; k < exact.depth.depth_m.size(); ++k)
    biased += noisy.depth.depth_m[k] - exact.depth.depth_m[k] > 1e-4f;
  EXPECT_GT(biased, 500u);
  EXPECT_LT(biased, exact.depth.depth_m.size() / 2);
}

TEST(Noise, DropoutsGrowAtGrazingIncidence) {
  NoiseConfig noise = NoiseConfig::none();
  noise.dropout_enabled = true;
  auto dropped_fraction = [&](double tilt_deg) {
    const DepthRenderer r = plane_renderer(2.0, tilt_deg, noise);
    DepthImage exact, noisy;
    r.render(Pose::Identity(), 5, false, &exact, nullptr);
    r.render(Pose::Identity(), 5, true, &noisy, nullptr);
    size_t valid = 0, dropped = 0;
    for (size_t k = 0; k < exact.depth_m.size(); ++k) {
      if (exact.depth_m[k] <= 0) continue;
      ++valid;
      dropped += noisy.depth_m[k] == 0.0f;
    }
    return static_cast<double>(dropped) / valid;
  };
  const double frontal = dropped_fraction(0.0);
  EXPECT_NEAR(frontal, noise.dropout_probability, 0.001);
  EXPECT_GT(dropped_fraction(70.0), 10 * frontal);
}

TEST(Noise, OutliersAreSparseAndWithinTheRange) {
  NoiseConfig noise = NoiseConfig::none();
  noise.outlier_enabled = true;
  noise.outlier_probability = 0.01;
  const DepthRenderer r = plane_renderer(2.0, 0.0, noise);
  DepthImage noisy;
  r.render(Pose::Identity(), 9, true, &noisy, nullptr);
  size_t outliers = 0;
  for (float z : noisy.depth_m) {
    ASSERT_GE(z, 0.5f);
    ASSERT_LE(z, 4.5f);
    outliers += std::fabs(z - 2.0f) > 1e-5f;
  }
  EXPECT_NEAR(static_cast<double>(outliers) / noisy.depth_m.size(), 0.01, 0.002);
}

TEST(Noise, DefaultsAreAllOnAndValidated) {
  const NoiseConfig d;
  EXPECT_TRUE(d.enabled && d.axial_enabled && d.flying_enabled && d.mpi_enabled &&
              d.dropout_enabled && d.outlier_enabled);
  EXPECT_TRUE(d.validate().is_ok());
  NoiseConfig bad;
  bad.flying_probability = 1.5;
  ASSERT_FALSE(bad.validate().is_ok());
  EXPECT_NE(bad.validate().message().find("flying_probability"), std::string::npos);
  SyntheticConfig c;
  c.noise.mpi_range_m = -1;
  auto s = SyntheticSequence::create(c);
  ASSERT_FALSE(s.is_ok());
  EXPECT_NE(s.status().message().find("mpi_range_m"), std::string::npos);

  // With everything on, a frame stays close to the truth almost everywhere.
  const SyntheticSequence seq = make_sequence(SceneKind::kCorner, 60);
  const Frame exact = seq.render(30, false);
  const Frame noisy = seq.render(30, true);
  size_t close = 0, valid = 0;
  for (size_t k = 0; k < exact.depth.depth_m.size(); ++k) {
    if (exact.depth.depth_m[k] <= 0) continue;
    ++valid;
    close += std::fabs(noisy.depth.depth_m[k] - exact.depth.depth_m[k]) < 0.02f;
  }
  EXPECT_GT(static_cast<double>(close) / valid, 0.97);
}

TEST(Render, ColourIsRegisteredToDepth) {
  const SyntheticSequence seq = make_sequence(SceneKind::kRoom, 60);
  const Frame f = seq.render(12, false);
  ASSERT_EQ(f.color.width, f.depth.width);
  ASSERT_EQ(f.color.height, f.depth.height);
  ASSERT_EQ(f.color.rgb.size(), f.depth.depth_m.size() * 3);
  // Depth edges (box outlines) are colour edges too: the colour image is not a constant.
  size_t lit = 0, changes = 0;
  for (size_t k = 0; k + 1 < f.depth.depth_m.size(); ++k) {
    lit += f.color.rgb[3 * k] + f.color.rgb[3 * k + 1] + f.color.rgb[3 * k + 2] > 0;
    changes += f.color.rgb[3 * k] != f.color.rgb[3 * k + 3];
  }
  EXPECT_EQ(lit, f.depth.depth_m.size() - 1);  // every pixel sees a surface in the closed room
  EXPECT_GT(changes, 1000u);

  // Nothing hit, nothing lit: half of the view looks past a plane.
  auto scene = Scene::create({Primitive::plane(Vector3d(0, 0, 2), -Vector3d::UnitZ(),
                                               Vector3d::UnitX(), 0, 10, -10, 10, "half")});
  ASSERT_TRUE(scene.is_ok());
  const DepthRenderer r(std::make_shared<const Scene>(std::move(scene).value()), RendererConfig());
  DepthImage depth;
  ColorImage color;
  r.render(Pose::Identity(), 0, false, &depth, &color);
  for (size_t k = 0; k < depth.depth_m.size(); ++k) {
    const bool has_colour = color.rgb[3 * k] + color.rgb[3 * k + 1] + color.rgb[3 * k + 2] > 0;
    ASSERT_EQ(depth.depth_m[k] > 0, has_colour) << "pixel " << k;
  }
}

TEST(Render, ConcurrentRenderingGivesTheSameFrames) {
  const SyntheticSequence seq = make_sequence(SceneKind::kRooms, 1000);
  std::vector<Frame> a(4), b(4);
  std::thread t1([&] {
    for (size_t k = 0; k < 4; ++k) a[k] = seq.render(100 * k);
  });
  std::thread t2([&] {
    for (size_t k = 0; k < 4; ++k) b[3 - k] = seq.render(100 * (3 - k));
  });
  t1.join();
  t2.join();
  for (size_t k = 0; k < 4; ++k) {
    EXPECT_EQ(a[k].depth.depth_m, b[k].depth.depth_m);
    EXPECT_EQ(a[k].color.rgb, b[k].color.rgb);
  }
}

}  // namespace
}  // namespace depthfuse::synthetic
