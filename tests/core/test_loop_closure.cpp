// Loop closure's parts on the analytic corner: the ICP that verifies a candidate, a drifted loop
// closed where the odometry was blind, and an identical place that the odometry puts metres away
// refused (the twin rooms' case).
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <random>

#include "cloud_icp.hpp"
#include "core_test_util.hpp"
#include "depthfuse/scan_graph.hpp"
#include "loop_closure.hpp"

using namespace depthfuse;

namespace {

KeyframeCloud cloud_of(const Pose& T_world_cam, const LoopClosureConfig& c) {
  const Frame f = test::render_corner(T_world_cam);
  MeasurementImage m;
  EXPECT_TRUE(backproject(f, SensorModelConfig{}, FusionConfig{}, &m).is_ok());
  return make_keyframe_cloud(m, c);
}

// A camera on a circle of radius 2.4 m round the corner's vertical axis, looking into it.
Pose on_arc(double azimuth_deg, double height_m = 1.4) {
  const double a = azimuth_deg * M_PI / 180.0;
  return test::look_at({2.4 * std::cos(a), 2.4 * std::sin(a), height_m}, {0.3, 0.3, 0.4});
}

double angle_deg(const Pose& a, const Pose& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle() * 180.0 / M_PI;
}

// The next keyframe of `s`: where the graph puts it, the points of the view from T_world_view,
// and after the first the odometry edge from the keyframe before, as the graph has the two, of
// covariance `cov`.
void append_keyframe(GraphSnapshot* s, const Pose& T_world_kf, const Pose& T_world_view,
                     const Matrix6d& cov, const LoopClosureConfig& c) {
  const size_t k = s->keyframes.size();
  GraphKeyframe kf;
  kf.frame_id = static_cast<uint32_t>(1 + 10 * k);
  kf.T_world_kf = T_world_kf;
  kf.cloud = std::make_shared<const KeyframeCloud>(cloud_of(T_world_view, c));
  s->keyframes.push_back(kf);
  if (k == 0) return;
  PoseGraphEdge e;
  e.from = static_cast<uint32_t>(k - 1);
  e.to = static_cast<uint32_t>(k);
  e.T_from_to = s->keyframes[k - 1].T_world_kf.inverse() * T_world_kf;
  e.information = cov.inverse();
  s->odometry.push_back(e);
  s->odometry_covariance.push_back(cov);
}

}  // namespace

TEST(CloudIcp, RecoversTheRelativePoseOfTwoViews) {
  const LoopClosureConfig c;
  const Pose A = on_arc(30), B = on_arc(36, 1.5);
  const KeyframeCloud a = cloud_of(A, c), b = cloud_of(B, c);
  ASSERT_GT(a.size(), 500u);
  const Pose truth = A.inverse() * B;
  Vector6d off;
  off << 0.02, -0.01, 0.015, 0.03, -0.02, 0.025;  // ~1.6 degrees and 4 cm
  const CloudAlignment r = align_clouds(b, a, apply_delta(truth, off), c);
  ASSERT_TRUE(r.converged);
  EXPECT_GT(r.overlap, 0.6);
  EXPECT_LT((r.T_target_source.translation() - truth.translation()).norm(), 3e-3);
  EXPECT_LT(angle_deg(r.T_target_source, truth), 0.2);
  // Three planes constrain every direction.
  EXPECT_GT(Eigen::SelfAdjointEigenSolver<Matrix6d>(r.information).eigenvalues()(0), 1.0);
}

// A bare wall seen from two places along it, with noise: the depth says nothing of the motion
// along the wall, and the alignment must not claim it did. The normals' noise gives the normal
// equations curvature along the wall; the information keeps only what the cost shows.
TEST(CloudIcp, ClaimsNothingAlongABareWall) {
  const LoopClosureConfig c;
  const Eigen::Vector3d n(0, 1, 0);  // the wall y = 0
  const Pose A = test::look_at({1.0, 2.5, 1.4}, {1.0, 0.0, 1.4});
  const Pose B = test::look_at({1.137, 2.5, 1.4}, {1.137, 0.0, 1.4});
  std::mt19937 rng(7);
  std::normal_distribution<float> noise_m(0.0f, 0.003f);
  const auto noisy_cloud = [&](const Pose& T_world_cam) {
    Frame f = test::render_plane(T_world_cam, n, 0.0);
    for (float& d : f.depth.depth_m)
      if (d > 0) d += noise_m(rng);
    MeasurementImage m;
    EXPECT_TRUE(backproject(f, SensorModelConfig{}, FusionConfig{}, &m).is_ok());
    return make_keyframe_cloud(m, c);
  };
  const KeyframeCloud a = noisy_cloud(A), b = noisy_cloud(B);
  ASSERT_GT(a.size(), 500u);
  const Pose truth = A.inverse() * B;
  // The graph's guess is 10 cm off along the wall (the camera's x in both views).
  const Pose guess = truth * Eigen::Translation3d(0.10, 0, 0);
  const CloudAlignment r = align_clouds(b, a, guess, c);
  ASSERT_TRUE(r.converged);
  // In B's frame: along the wall (x), and the wall's normal (z, the optical axis).
  Vector6d along = Vector6d::Zero(), normal = Vector6d::Zero();
  along(3) = 1;
  normal(5) = 1;
  EXPECT_LT(along.dot(r.information * along), 1000.0) << "a sigma under 3 cm along the wall";
  EXPECT_GT(normal.dot(r.information * normal), 1e4) << "a sigma over 1 cm across the wall";
  // What the alignment does say, it says right: the distance to the wall.
  EXPECT_LT(std::abs(r.T_target_source.translation().z() - truth.translation().z()), 3e-3);
}

// Out along the arc and back: the odometry drifts upwards (a direction it was told it could not
// see), and the way back passes the way out. The loop edges put the keyframes back; the drift goes
// where the odometry's information was weak.
TEST(LoopCloser, ClosesADriftedLoopWhereTheOdometryWasBlind) {
  LoopClosureConfig c;
  c.min_keyframes_back = 6;
  c.min_path_m = 0.5;
  std::vector<Pose> truth, drifted;
  for (int k = 0; k <= 10; ++k) truth.push_back(on_arc(15 + 6 * k));
  for (int k = 9; k >= 0; --k) truth.push_back(on_arc(15 + 6 * k + 1.5, 1.45));
  GraphSnapshot s;
  Matrix6d cov = Matrix6d::Identity() * 1e-8;
  cov(5, 5) = 1e-4;  // 1 cm a step along the camera's z, which the odometry does not see
  for (size_t k = 0; k < truth.size(); ++k) {
    // 8 mm of drift a keyframe along the camera's optical axis.
    Pose d = k == 0 ? truth[0] : drifted.back() * (truth[k - 1].inverse() * truth[k]);
    if (k > 0) d = d * Eigen::Translation3d(0, 0, 0.008);
    drifted.push_back(d);
    append_keyframe(&s, d, truth[k], cov, c);
  }
  const double drift_before = (drifted.back().translation() - truth.back().translation()).norm();
  ASSERT_GT(drift_before, 0.1);
  LoopCloser closer(c, RelocalisationConfig{}, /*background=*/false);
  closer.submit(s);
  const std::optional<GraphCorrection> r = closer.take();
  ASSERT_TRUE(r.has_value());
  EXPECT_GE(r->loops.size(), 3u);
  EXPECT_EQ(closer.stats().rejected, 0u);
  for (size_t k = 0; k < truth.size(); ++k)
    EXPECT_LT((r->T_world_kf[k].translation() - truth[k].translation()).norm(), 0.02) << k;
  EXPECT_LT((r->T_world_kf.back().translation() - truth.back().translation()).norm(), 5e-3);
}

// Out along the arc and back, the odometry right: every loop the way back finds agrees with the
// graph as it stands. They are kept, and no optimisation runs for them: in a long scan of one room
// most keyframes find such loops, and a solve costs time that grows with the graph.
TEST(LoopCloser, KeepsLoopsThatAgreeWithTheGraphWithoutOptimising) {
  LoopClosureConfig c;
  c.min_keyframes_back = 6;
  c.min_path_m = 0.5;
  GraphSnapshot s;
  Matrix6d cov = Matrix6d::Identity() * 1e-8;
  cov(5, 5) = 1e-4;  // 1 cm a step along the camera's z, which the odometry does not see
  std::vector<Pose> truth;
  for (int k = 0; k <= 10; ++k) truth.push_back(on_arc(15 + 6 * k));
  for (int k = 9; k >= 0; --k) truth.push_back(on_arc(15 + 6 * k));  // the same places
  for (const Pose& T : truth) append_keyframe(&s, T, T, cov, c);
  LoopCloser closer(c, RelocalisationConfig{}, /*background=*/false);
  closer.submit(s);
  EXPECT_FALSE(closer.take().has_value());
  LoopClosureStats stats = closer.stats();
  EXPECT_GE(stats.loops, 3u) << "no loop found: the test tests nothing";
  EXPECT_EQ(stats.optimisations, 0u);
  EXPECT_GE(stats.loops_agreed, 1u);

  // The way back's last keyframe drifted 2 cm along its optical axis, where the odometry is blind:
  // its loop disagrees, and the optimisation that follows has the loops that agreed as well.
  s.keyframes.back().T_world_kf = truth.back() * Eigen::Translation3d(0, 0, 0.02);
  s.odometry.back().T_from_to =
      s.keyframes[s.keyframes.size() - 2].T_world_kf.inverse() * s.keyframes.back().T_world_kf;
  LoopCloser again(c, RelocalisationConfig{}, /*background=*/false);
  again.submit(s);
  const std::optional<GraphCorrection> r = again.take();
  ASSERT_TRUE(r.has_value());
  stats = again.stats();
  EXPECT_EQ(stats.optimisations, 1u);
  EXPECT_EQ(r->loops.size(), stats.loops);
  EXPECT_LT((r->T_world_kf.back().translation() - truth.back().translation()).norm(), 5e-3);
}

// The same view of a corner twice, three metres apart by the odometry, which knows where it went
// to a centimetre: the place search finds the first view alike and ICP aligns the two perfectly,
// but the correction is far beyond what the odometry allows. Refused: no loop, no correction.
TEST(LoopCloser, RefusesAnIdenticalPlaceTheOdometryPutsElsewhere) {
  LoopClosureConfig c;
  c.min_keyframes_back = 5;
  c.min_path_m = 1.0;
  c.place_search_every_n_keyframes = 1;
  GraphSnapshot s;
  const Matrix6d cov = Matrix6d::Identity() * 1e-6;
  const Pose view = on_arc(45);
  for (int k = 0; k <= 8; ++k) {
    // The first and the last see the same (twin) corner from the same place relative to it.
    append_keyframe(&s, Eigen::Translation3d(0.375 * k, -0.375 * k, 0) * view,  // 3 m in all
                    k == 0 || k == 8 ? view : on_arc(45 + 5 * k, 1.2 + 0.05 * k), cov, c);
  }
  LoopCloser closer(c, RelocalisationConfig{}, /*background=*/false);
  closer.submit(s);
  EXPECT_FALSE(closer.take().has_value());
  const LoopClosureStats stats = closer.stats();
  EXPECT_GE(stats.place_searches, 1u);
  EXPECT_GE(stats.gated, 1u) << "the twin was never aligned: the test tests nothing";
  EXPECT_EQ(stats.loops, 0u);
}

// Out along the arc and back past the same places, each frame a keyframe, the loop closer
// searching each as it comes, the clouds over their memory bound from the start: a keyframe gives
// its points up once it has been searched and an older one that kept its points covers its place.
// The way back keeps none, so the graph's memory stays what the way out needed, and the way back
// still closes loops against the way out.
TEST(ScanGraph, KeepsOneCloudAPlaceAndStillClosesLoops) {
  LoopClosureConfig c;
  c.min_keyframes_back = 4;
  c.min_path_m = 0.5;
  c.max_cloud_mib = 0;
  std::vector<Pose> poses;
  for (int k = 0; k <= 10; ++k) poses.push_back(on_arc(15 + 6 * k));
  const size_t way_out = poses.size();
  for (int k = 8; k >= 0; --k) poses.push_back(on_arc(15 + 6 * k + 2, 1.42));
  ScanGraph graph(c);
  LoopCloser closer(c, RelocalisationConfig{}, /*background=*/false);
  size_t bytes_after_way_out = 0;
  for (size_t k = 0; k < poses.size(); ++k) {
    MeasurementImage m;
    ASSERT_TRUE(backproject(test::render_corner(poses[k]), SensorModelConfig{}, FusionConfig{}, &m).is_ok());
    ASSERT_TRUE(graph.frame_fused(static_cast<uint32_t>(1 + k), static_cast<int64_t>(k) * 33000,
                                  poses[k], Matrix6d::Identity() * 1e-8, m))
        << "frame " << k << " is no keyframe: the test's spacing is wrong";
    // Not searched yet: the newest keyframe keeps its points whatever is near.
    graph.forget_redundant_clouds(k);
    EXPECT_GT(graph.keyframes().back().cloud->size(), 0u) << k;
    GraphSnapshot s;
    s.keyframes = graph.keyframes();
    s.odometry = graph.odometry();
    s.odometry_covariance = graph.odometry_covariance();
    closer.submit(std::move(s));
    ASSERT_EQ(closer.searched(), k + 1);
    graph.forget_redundant_clouds(closer.searched());
    if (k + 1 == way_out) bytes_after_way_out = graph.memory_bytes();
  }
  const std::vector<GraphKeyframe>& kfs = graph.keyframes();
  size_t kept_out = 0, kept_back = 0;
  for (size_t k = 0; k < kfs.size(); ++k) {
    ASSERT_TRUE(kfs[k].cloud);
    EXPECT_GT(*std::max_element(kfs[k].cloud->thumbnail.begin(), kfs[k].cloud->thumbnail.end()), 0.0f)
        << "keyframe " << k << " lost its thumbnail too";
    if (kfs[k].cloud->size() == 0) continue;
    (k < way_out ? kept_out : kept_back) += 1;
    for (size_t i = 0; i < k; ++i) {  // no two kept clouds share a place
      if (kfs[i].cloud->size() == 0) continue;
      EXPECT_FALSE((kfs[i].T_world_kf.translation() - kfs[k].T_world_kf.translation()).norm() <
                       c.cloud_spacing_m &&
                   angle_deg(kfs[i].T_world_kf, kfs[k].T_world_kf) < c.cloud_spacing_deg)
          << "keyframes " << i << " and " << k;
    }
  }
  EXPECT_GE(kept_out, 4u);
  EXPECT_LT(kept_out, way_out) << "0.25 m apart, neighbours on the way out share a place";
  EXPECT_EQ(kept_back, 0u);
  // The way back's keyframes cost their poses, edges and thumbnails: far less than their clouds.
  EXPECT_LT(graph.memory_bytes() - bytes_after_way_out,
            (kfs.size() - way_out) * kfs[0].cloud->memory_bytes() / 4);
  EXPECT_GE(closer.stats().loops, 3u) << "the way back no longer closes against the way out";

  // A resumed graph gives up the same points, whatever its file held; 0: every keyframe keeps its
  // points.
  ScanGraphState full = graph.state();
  for (GraphKeyframe& k : full.keyframes)
    if (k.cloud->size() == 0) k.cloud = kfs[0].cloud;
  ScanGraph resumed(c);
  ASSERT_TRUE(resumed.restore(full).is_ok());
  size_t kept_resumed = 0;
  for (const GraphKeyframe& k : resumed.keyframes()) kept_resumed += k.cloud->size() > 0;
  EXPECT_EQ(kept_resumed, kept_out + kept_back);
  c.cloud_spacing_m = 0;
  ScanGraph all(c);
  ASSERT_TRUE(all.restore(full).is_ok());
  for (const GraphKeyframe& k : all.keyframes()) EXPECT_GT(k.cloud->size(), 0u);

  // Within the bound every keyframe keeps its points; just over it, the oldest redundant ones go
  // until the clouds are within it again.
  c.cloud_spacing_m = LoopClosureConfig{}.cloud_spacing_m;
  c.max_cloud_mib = 1.0;
  ScanGraph roomy(c);
  ASSERT_TRUE(roomy.restore(full).is_ok());
  for (const GraphKeyframe& k : roomy.keyframes()) EXPECT_GT(k.cloud->size(), 0u);
  size_t clouds_bytes = 0;
  for (const GraphKeyframe& k : full.keyframes) clouds_bytes += k.cloud->memory_bytes();
  const size_t one_cloud = kfs[0].cloud->memory_bytes();
  c.max_cloud_mib = static_cast<double>(clouds_bytes - 2 * one_cloud) / (1024.0 * 1024.0);
  ScanGraph tight(c);
  ASSERT_TRUE(tight.restore(full).is_ok());
  size_t kept_tight = 0, tight_bytes = 0;
  for (const GraphKeyframe& k : tight.keyframes()) {
    kept_tight += k.cloud->size() > 0;
    tight_bytes += k.cloud->memory_bytes();
  }
  EXPECT_LT(kept_tight, full.keyframes.size());
  EXPECT_GT(kept_tight, kept_out + kept_back) << "more went than the bound asked";
  EXPECT_LE(tight_bytes, clouds_bytes - 2 * one_cloud);
}
