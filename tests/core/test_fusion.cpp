// Fusion against analytic expectations: the merge rule, uncertainty, violations, post-filter.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>

#include "core_test_util.hpp"
#include "depthfuse/fusion.hpp"

using namespace depthfuse;

namespace {

Eigen::Matrix3f iso_information(float sigma_m) {
  return Eigen::Matrix3f::Identity() / (sigma_m * sigma_m);
}

struct Fixture {
  SensorModelConfig sensor;
  FusionConfig fusion;
  PointMap map{0.5};
  Fuser fuser{sensor, fusion};
  MeasurementImage m;
  uint32_t frame_id = 1;

  FusionStats fuse(const Frame& f, const Pose& T) {
    EXPECT_TRUE(backproject(f, sensor, fusion, &m).is_ok());
    return fuser.fuse(m, nullptr, T, frame_id++, &map);
  }
};

double mean_uncertainty(const PointMap& map) {
  const PointArrays a = map.gather();
  double s = 0;
  for (size_t i = 0; i < a.size(); ++i) s += uncertainty_m(a, i);
  return s / a.size();
}

}  // namespace

TEST(MergeRule, EqualCertaintyMeetsHalfwayAndShrinks) {
  const Eigen::Vector3f a(0, 0, 2), b(0, 0, 2.002f);
  Eigen::Vector3f p;
  Eigen::Matrix3f L;
  ASSERT_TRUE(merge_measurement(a, iso_information(0.003f), b, iso_information(0.003f), &p, &L));
  EXPECT_NEAR(p.z(), 2.001f, 1e-6f);
  // Two equal measurements: the variance halves.
  EXPECT_NEAR(L(0, 0), 2.0f / (0.003f * 0.003f), 1.0f);
}

TEST(MergeRule, WeightsTowardsTheMoreCertain) {
  const Eigen::Vector3f e(0, 0, 2), n(0, 0, 2.003f);
  Eigen::Vector3f p;
  Eigen::Matrix3f L;
  ASSERT_TRUE(merge_measurement(e, iso_information(0.001f), n, iso_information(0.004f), &p, &L));
  const float d_e = (p - e).norm(), d_n = (p - n).norm();
  EXPECT_LT(d_e, d_n);
  EXPECT_NEAR(d_e / (d_e + d_n), 1.0f / 17.0f, 1e-3f);  // variance ratio 1:16
}

TEST(MergeRule, FarApartDoNotMerge) {
  Eigen::Vector3f p;
  Eigen::Matrix3f L;
  EXPECT_FALSE(merge_measurement({0, 0, 2}, iso_information(0.003f), {0, 0, 2.05f},
                                 iso_information(0.003f), &p, &L));
  EXPECT_FALSE(merge_measurement({0, 0, 2}, iso_information(0.003f), {0.05f, 0, 2},
                                 iso_information(0.003f), &p, &L));
}

TEST(Fuser, SecondViewOfTheSameSurfaceMerges) {
  Fixture fx;
  const Frame f = test::render_plane(Pose::Identity(), Eigen::Vector3d::UnitZ(), 2.0);
  const FusionStats first = fx.fuse(f, Pose::Identity());
  EXPECT_EQ(first.added, first.measurements);
  const size_t points = fx.map.point_count();
  const double u1 = mean_uncertainty(fx.map);
  const FusionStats second = fx.fuse(f, Pose::Identity());
  EXPECT_GT(second.merged, second.measurements * 99 / 100);
  EXPECT_LT(fx.map.point_count(), points + points / 100);
  EXPECT_LT(mean_uncertainty(fx.map), u1 / std::sqrt(2.0) * 1.01);
}

TEST(Fuser, ShiftedViewStillMergesOnThePlane) {
  // A second view 5 cm to the side: its samples fall between the first view's; they still merge.
  Fixture fx;
  const Frame a = test::render_plane(Pose::Identity(), Eigen::Vector3d::UnitZ(), 2.0);
  Pose T = Pose::Identity();
  T.translation() = Eigen::Vector3d(0.05, 0.0, 0.0);
  const Frame b = test::render_plane(T, Eigen::Vector3d::UnitZ(), 2.0);
  fx.fuse(a, Pose::Identity());
  const FusionStats s = fx.fuse(b, T);
  EXPECT_GT(s.merged, s.measurements * 8 / 10);
  // Fused points stay on the plane.
  const PointArrays pts = fx.map.gather();
  for (size_t i = 0; i < pts.size(); i += 97) EXPECT_NEAR(pts.position_m[i].z(), 2.0f, 1e-4f);
}

TEST(Fuser, SeenThroughPointCountsViolationAndPostfilterRemovesIt) {
  Fixture fx;
  const Frame near = test::render_plane(Pose::Identity(), Eigen::Vector3d::UnitZ(), 2.0);
  const Frame far = test::render_plane(Pose::Identity(), Eigen::Vector3d::UnitZ(), 2.1);
  fx.fuse(near, Pose::Identity());
  const size_t first = fx.map.point_count();
  const FusionStats s = fx.fuse(far, Pose::Identity());
  EXPECT_EQ(s.merged, 0u);
  EXPECT_GT(s.violations, first * 9 / 10);
  EXPECT_EQ(postfilter(&fx.map), s.violations);  // the seen-through plane goes, the far one stays
  EXPECT_EQ(fx.map.point_count(), s.added);
}

TEST(Fuser, DistantSurfaceBehindIsNoViolation) {
  // 50 % farther: outside |s_e - s_n| < 0.1 s_n, e.g. a surface seen past an occluder edge.
  Fixture fx;
  fx.fuse(test::render_plane(Pose::Identity(), Eigen::Vector3d::UnitZ(), 2.0), Pose::Identity());
  const FusionStats s =
      fx.fuse(test::render_plane(Pose::Identity(), Eigen::Vector3d::UnitZ(), 3.0), Pose::Identity());
  EXPECT_EQ(s.violations, 0u);
  EXPECT_EQ(s.merged, 0u);
}

TEST(Fuser, RedundantMeasurementIsDroppedNotLayered) {
  // Four views make the points of a plane at 2 m four times as certain as one measurement (three
  // merges each). At 2 m a measurement's ellipsoid reaches sqrt(lambda2) sigma = 2 x 1.7 mm = 3.4 mm
  // along the ray. A fifth view 5 mm farther fails the merge rule: the fused point would sit 4 mm
  // from the new measurement, outside its ellipsoid. Each existing point is 5 / 3.4 = 1.5
  // ellipsoids away, inside a gate of 2: if the points count as established (min merges 3) the
  // measurements are dropped instead of adding a second layer. If they are too young (min merges
  // 10) or the gate is off, the measurements become new points.
  struct Case {
    double gate;
    int min_merges;
    bool dropped;
  };
  for (const Case c : {Case{2.0, 3, true}, Case{2.0, 10, false}, Case{0.0, 0, false}}) {
    SCOPED_TRACE("gate " + std::to_string(c.gate) + ", min merges " + std::to_string(c.min_merges));
    Fixture fx;
    fx.sensor.lambda1 = 8.0;  // the ellipsoid above, whatever the defaults: 0.82 footprints wide
    fx.sensor.lambda2 = 4.0;  // ... and 2 sigma deep
    fx.fusion.redundancy_gate = c.gate;
    fx.fusion.redundancy_min_merges = c.min_merges;
    Fuser fuser(fx.sensor, fx.fusion);
    auto fuse = [&](double depth_m) {
      const Frame f = test::render_plane(Pose::Identity(), Eigen::Vector3d::UnitZ(), depth_m);
      EXPECT_TRUE(backproject(f, fx.sensor, fx.fusion, &fx.m).is_ok());
      return fuser.fuse(fx.m, nullptr, Pose::Identity(), fx.frame_id++, &fx.map);
    };
    for (int i = 0; i < 4; ++i) fuse(2.0);
    const size_t points = fx.map.point_count();
    const FusionStats s = fuse(2.005);
    EXPECT_LT(s.merged, s.measurements / 100);
    EXPECT_EQ(fx.map.point_count(), points + s.added);
    if (c.dropped) {
      EXPECT_GT(s.redundant, s.measurements * 99 / 100);
      EXPECT_LT(s.added, s.measurements / 100);
    } else {
      EXPECT_EQ(s.redundant, 0u);
      EXPECT_EQ(s.added, s.measurements - s.merged);
    }
  }
}

TEST(Fuser, NewSurfaceIsAddedDespiteTheGate) {
  // 2 cm behind a known plane is not the same surface: well outside twice the ellipsoid.
  Fixture fx;
  fx.fuse(test::render_plane(Pose::Identity(), Eigen::Vector3d::UnitZ(), 2.0), Pose::Identity());
  const FusionStats s =
      fx.fuse(test::render_plane(Pose::Identity(), Eigen::Vector3d::UnitZ(), 2.02), Pose::Identity());
  EXPECT_EQ(s.redundant, 0u);
  EXPECT_EQ(s.added, s.measurements);
}

TEST(Fuser, APointMergesWithSeveralMeasurementsOfOneFrame) {
  // A plane first seen from 2 m, then from 1.2 m straight on: the second camera's pixels are
  // smaller than the first's, so about 2.8 of its pixels see each existing point, and only one
  // of them has that point rendered at its own pixel. The others find it in their window and may
  // merge with it too (the paper loops over every pixel; a point is not limited to one merge per
  // frame). The frame's merges all land on existing points, and each is counted once.
  Fixture fx;
  const Eigen::Vector3d n = Eigen::Vector3d::UnitZ();
  fx.fuse(test::render_plane(Pose::Identity(), n, 2.0), Pose::Identity());
  const size_t points = fx.map.point_count();
  Pose closer = Pose::Identity();
  closer.translation().z() = 0.8;
  const FusionStats s = fx.fuse(test::render_plane(closer, n, 2.0), closer);
  const PointArrays a = fx.map.gather();
  size_t merges = 0, refined = 0, several = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    merges += a.state[i].merges;
    refined += a.state[i].merges >= 1;
    several += a.state[i].merges >= 2;
  }
  EXPECT_EQ(merges, s.merged);
  EXPECT_EQ(s.merged, s.measurements);  // every measurement merged: nothing added or dropped
  EXPECT_GT(s.merged, 2 * refined);     // more than two merges per refined point ...
  EXPECT_GT(several, refined / 2);      // ... and most refined points merged several times
  EXPECT_EQ(fx.map.point_count(), points + s.added);
  std::printf("%zu points; second frame: %zu measurements, %zu merged into %zu points, %zu of "
              "them twice or more\n",
              points, s.measurements, s.merged, refined, several);
}

TEST(Fuser, AMergeSeesTheEarlierMergesOfItsRow) {
  // One point P at pixel (u, v). The next frame measures pixels (u - 1, v) and (u, v) of one row.
  // Pixel u - 1 has no candidate of its own and merges with P from its window; pixel u then
  // merges with P as that merge left it, not with P as it was when the row was prepared
  // (fusion works out each pixel's merge with its own candidate for the whole row in advance).
  // Wide lateral ellipsoids (lambda1 = 32: 1.6 pixel footprints) let the neighbour merge.
  Fixture fx;
  fx.sensor.lambda1 = 32.0;
  Fuser fuser(fx.sensor, fx.fusion);
  const CameraIntrinsics K = CameraIntrinsics::kinect_v2();
  const int u = 260, v = 100;
  // Both frames also see a 16 x 16 pixel patch 20 rows above, in P's map chunk: fusion finds the
  // chunks from a sample of the pixels (one per 8 x 8 block), and two pixels alone may hold none.
  auto frame = [&](std::initializer_list<std::pair<int, float>> row_pixels) {
    Frame f;
    f.intrinsics = K;
    f.depth = DepthImage(K.width, K.height);
    for (int pv = v - 36; pv < v - 20; ++pv)
      for (int pu = u - 8; pu < u + 8; ++pu) f.depth.at(pu, pv) = 2.0f;
    for (const auto& [pu, depth_m] : row_pixels) f.depth.at(pu, v) = depth_m;
    EXPECT_TRUE(backproject(f, fx.sensor, fx.fusion, &fx.m).is_ok());
    return fx.m;
  };
  auto position = [&](const MeasurementImage& m, int pu) {
    const size_t i = static_cast<size_t>(v) * K.width + pu;
    return Eigen::Vector3f(m.x[i], m.y[i], m.z[i]);
  };
  const SensorModel model(fx.sensor, K);

  const MeasurementImage first = frame({{u, 2.0f}});
  fuser.fuse(first, nullptr, Pose::Identity(), 1, &fx.map);
  ASSERT_EQ(fx.map.point_count(), 1u + 256u);
  const Eigen::Vector3f p = position(first, u);

  const MeasurementImage second = frame({{u - 1, 2.001f}, {u, 1.999f}});
  const FusionStats s = fuser.fuse(second, nullptr, Pose::Identity(), 2, &fx.map);
  EXPECT_EQ(s.added, 0u);
  EXPECT_EQ(s.merged, 2u + 256u);
  const PointArrays a = fx.map.gather();
  ASSERT_EQ(a.size(), 1u + 256u);
  size_t j = 0;  // P: the point nearest where it was (the patch is over 10 cm away)
  for (size_t k = 1; k < a.size(); ++k)
    if ((a.position(k) - p).norm() < (a.position(j) - p).norm()) j = k;
  EXPECT_EQ(a.state[j].merges, 2);

  // The expected point: P merged with the measurement of u - 1, then with that of u.
  const Eigen::Vector3f m1 = position(second, u - 1), m2 = position(second, u);
  Eigen::Vector3f p1, p2, stale;
  Eigen::Matrix3f L1, L2, L_stale;
  ASSERT_TRUE(merge_measurement(p, model.information_cam(p), m1, model.information_cam(m1), &p1,
                                &L1));
  ASSERT_TRUE(merge_measurement(p1, L1, m2, model.information_cam(m2), &p2, &L2));
  ASSERT_TRUE(merge_measurement(p, model.information_cam(p), m2, model.information_cam(m2),
                                &stale, &L_stale));
  // The test can tell the two apart: P merged with u's measurement alone lies 1.9 mm away.
  ASSERT_GT((stale - p2).norm(), 1e-3f);
  EXPECT_LT((a.position(j) - p2).norm(), 1e-6f);
  EXPECT_NEAR(information_matrix(a, j)(2, 2), L2(2, 2), 1e-3f * L2(2, 2));
}

TEST(Fuser, AThinObjectMergesLikeAWall) {
  // A pole 4 pixels wide (2.2 cm at 2 m) in front of a wall at 3 m, seen twice from the same pose:
  // the second view refines the pole's points as it does the wall's, instead of adding a second
  // pole. Fusion finds the map's chunks from one sampled pixel per 8 x 8 block, and the pole's
  // chunk holds nothing else. The pole lies between the columns a fixed grid of samples would use
  // (the block centres, 4 + 8k), which never saw it.
  Fixture fx;
  const CameraIntrinsics K = CameraIntrinsics::kinect_v2();
  Frame f = test::render_plane(Pose::Identity(), Eigen::Vector3d::UnitZ(), 3.0);
  const int u0 = 261;  // columns 261-264, between 260 and 268
  for (int v = 0; v < K.height; ++v)
    for (int u = u0; u < u0 + 4; ++u) f.depth.at(u, v) = 2.0f;
  const size_t pole = 4 * static_cast<size_t>(K.height);
  fx.fuse(f, Pose::Identity());
  const size_t points = fx.map.point_count();
  const FusionStats s = fx.fuse(f, Pose::Identity());
  EXPECT_EQ(s.added, 0u);
  EXPECT_GE(s.merged, s.measurements - s.redundant);
  EXPECT_EQ(fx.map.point_count(), points);
  std::printf("%zu points, %zu of them on the pole; second view: %zu merged, %zu added\n", points,
              pole, s.merged, s.added);
}

namespace {

// A wall seen first from first_m, exactly, then twenty times from then_m, each view shifted by a
// few millimetres and with the sensor model's Gaussian depth noise. Each point should come out as
// the information-weighted mean of the measurements merged into it: a point that k of the later
// measurements refined has the axial standard deviation sigma sqrt(k) / (r + k), where sigma is
// the noise at then_m and r = (sigma / sigma(first_m))^2 weighs its exact first measurement.
// Returns the rms over the points of their errors scaled by that prediction (1: as
// predicted), with their mean error and median |error|.
struct WallRefinement {
  size_t points = 0, unrefined = 0;
  double rms_normalised = 0, mean_m = 0, median_abs_m = 0;
};

WallRefinement refine_wall(double first_m, double then_m) {
  Fixture fx;
  const SensorModel model(fx.sensor, CameraIntrinsics::kinect_v2());
  const double sigma = model.axial_sigma_m(then_m);
  const double r = std::pow(sigma / model.axial_sigma_m(first_m), 2);
  const Eigen::Vector3d n = Eigen::Vector3d::UnitZ();
  const double wall_m = 3.0;
  Pose first = Pose::Identity();
  first.translation().z() = wall_m - first_m;
  fx.fuse(test::render_plane(first, n, wall_m), first);
  std::mt19937 rng(7);
  std::normal_distribution<float> noise(0.0f, static_cast<float>(sigma));
  std::uniform_real_distribution<double> shift(-4e-3, 4e-3);
  for (int k = 0; k < 20; ++k) {
    Pose then = Pose::Identity();
    then.translation() = Eigen::Vector3d(shift(rng), shift(rng), wall_m - then_m);
    Frame f = test::render_plane(then, n, wall_m);
    for (float& z : f.depth.depth_m)
      if (z > 0.0f) z += noise(rng);
    fx.fuse(f, then);
  }
  // The points that every later view saw (the middle of the nearer view): each should be refined.
  const double half_width_m = 0.25 * std::min(first_m, then_m);
  const PointArrays a = fx.map.gather();
  WallRefinement w;
  std::vector<double> abs_err;
  double sum = 0, z2 = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const Eigen::Vector3f& p = a.position_m[i];
    if (std::abs(p.x()) > half_width_m || std::abs(p.y()) > half_width_m) continue;
    const double e = p.z() - wall_m, k = a.state[i].merges;
    if (k < 1) {
      ++w.unrefined;
      continue;
    }
    const double expected = sigma * std::sqrt(k) / (r + k);
    abs_err.push_back(std::abs(e));
    sum += e;
    z2 += (e / expected) * (e / expected);
  }
  w.points = abs_err.size();
  if (w.points == 0) return w;
  std::sort(abs_err.begin(), abs_err.end());
  w.rms_normalised = std::sqrt(z2 / w.points);
  w.mean_m = sum / w.points;
  w.median_abs_m = abs_err[w.points / 2];
  std::printf("first from %.1f m, then from %.1f m: %zu points (%zu not refined), mean error %.3f mm, median |error| "
              "%.3f mm, rms %.3f of what their merges predict\n",
              first_m, then_m, w.points, w.unrefined, 1e3 * w.mean_m, 1e3 * w.median_abs_m, w.rms_normalised);
  return w;
}

// Every point refined, each as its merges predict (within 10 %), and no bias.
void expect_as_predicted(const WallRefinement& w, size_t min_points) {
  ASSERT_GT(w.points, min_points);
  EXPECT_EQ(w.unrefined, 0u);
  EXPECT_NEAR(w.rms_normalised, 1.0, 0.1);
  EXPECT_LT(std::abs(w.mean_m), 5e-5);
}

}  // namespace

TEST(Fuser, FarViewsRefineADenseCloudWithoutSpreadingIt) {
  // Each pixel of the views from 2 m covers about four of the points left by the view from 1 m.
  // A measurement refines the one of them that projects nearest its pixel's centre. Picking the
  // one nearest the measured depth instead paired each measurement with the point whose error
  // matched its noise, and the points drifted apart: rms 2.02 of the prediction, median |error|
  // 0.83 mm against 0.38, and 3.5 % of the points were never refined.
  expect_as_predicted(refine_wall(1.0, 2.0), 30000);
}

TEST(Fuser, NearViewsRefineASparseCloudWithoutSpreadingIt) {
  // Each point left by the view from 2 m is seen by about four pixels of the views from 1 m, and
  // only one of them has it as its own candidate: the others find it in their 3 x 3 window. The
  // window's nearest point is the nearest in the measurement's own metric, which weighs depth
  // less than the offset across the ray. By plain distance the neighbour whose error matched the
  // measurement's noise won: rms 1.26 of the prediction, median |error| 0.15 mm against 0.12.
  expect_as_predicted(refine_wall(2.0, 1.0), 8000);
}

// The map's budget counts the capacity a chunk holds: a chunk loaded back holds exactly its points,
// and one more must not double it (std::vector's growth), nor must appending a few.
TEST(PointArrays, GrowsByAnEighthNotByDoubling) {
  PointArrays a;
  a.resize(8000);
  a.position_m.shrink_to_fit();
  a.state.shrink_to_fit();
  ASSERT_EQ(a.memory_bytes(), 8000 * PointArrays::kBytesPerPoint);
  a.push_back(Eigen::Vector3f(1, 2, 3), PointState{});
  EXPECT_EQ(a.size(), 8001u);
  EXPECT_LE(a.memory_bytes(), (8000 + 1000 + 16) * PointArrays::kBytesPerPoint);
  PointArrays b;
  b.resize(10);
  const size_t before = a.position_m.capacity();
  for (int i = 0; i < 200; ++i) a.append(b);
  EXPECT_EQ(a.size(), 10001u);
  EXPECT_LE(a.position_m.capacity(), 10001u + 10001u / 8 + 16);
  EXPECT_GE(a.position_m.capacity(), before);
}
