// Re-registration recovers a known offset on the concave corner.
#include <gtest/gtest.h>

#include <cstring>

#include "core_test_util.hpp"
#include "depthfuse/fusion.hpp"
#include "depthfuse/registration.hpp"

using namespace depthfuse;

namespace {

Pose perturb(const Pose& T, const Eigen::Vector3d& dt_m, const Eigen::Vector3d& axis, double deg) {
  Pose D = Pose::Identity();
  D.linear() = Eigen::AngleAxisd(deg * M_PI / 180.0, axis.normalized()).toRotationMatrix();
  D.translation() = dt_m;
  return D * T;
}

double rotation_deg(const Pose& a, const Pose& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle() * 180.0 / M_PI;
}

// The corner fused from three views. `speckle` scales every 97th depth (or drops it): outliers and
// holes, some on the rows where the image splits in two halves.
struct CornerMap {
  SensorModelConfig sensor;
  FusionConfig fusion;
  PointMap map{0.5};
  explicit CornerMap(int threads = FusionConfig{}.threads, bool speckle = false) {
    fusion.threads = threads;
    Fuser fuser(sensor, fusion);
    MeasurementImage m;
    uint32_t id = 1;
    for (const Eigen::Vector3d& eye : {Eigen::Vector3d(2.0, 1.6, 1.4), Eigen::Vector3d(1.5, 2.1, 1.3),
                                      Eigen::Vector3d(2.2, 2.2, 1.6)}) {
      const Pose T = test::look_at(eye, Eigen::Vector3d(0.3, 0.3, 0.3));
      Frame f = test::render_corner(T);
      if (speckle) {
        for (size_t i = id; i < f.depth.depth_m.size(); i += 97) f.depth.depth_m[i] *= (i % 2) ? 1.02f : 0.0f;
      }
      EXPECT_TRUE(backproject(f, sensor, fusion, &m).is_ok());
      fuser.fuse(m, nullptr, T, id++, &map);
    }
  }
};

}  // namespace

TEST(Registration, RecoversTwoCentimetresAndOneDegreeOnTheCorner) {
  CornerMap corner;
  const Pose truth = test::look_at({1.8, 1.9, 1.5}, {0.3, 0.3, 0.3});
  MeasurementImage m;
  ASSERT_TRUE(backproject(test::render_corner(truth), corner.sensor, corner.fusion, &m).is_ok());

  Registrar reg(RegistrationConfig{});
  int trial = 0;
  for (const Eigen::Vector3d& axis : {Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0.3, 1, -0.2),
                                     Eigen::Vector3d(-1, 1, 1)}) {
    const Eigen::Vector3d dt = 0.02 * Eigen::Vector3d(std::cos(trial), std::sin(trial), 0.5).normalized();
    const Pose initial = perturb(truth, dt, axis, 1.0);
    const RegistrationResult r = reg.refine(m, corner.map, initial);
    ASSERT_TRUE(r.converged) << "trial " << trial;
    EXPECT_LT((r.T_world_cam.translation() - truth.translation()).norm(), 1e-3) << "trial " << trial;
    EXPECT_LT(rotation_deg(r.T_world_cam, truth), 0.05) << "trial " << trial;
    EXPECT_GT(r.fitness, 0.5);
    EXPECT_LT(r.rmse_m, 1e-3);
    ++trial;
  }
}

TEST(Registration, TrackingHandlesLargerMotionCoarseToFine) {
  CornerMap corner;
  const Pose truth = test::look_at({1.8, 1.9, 1.5}, {0.3, 0.3, 0.3});
  MeasurementImage m;
  ASSERT_TRUE(backproject(test::render_corner(truth), corner.sensor, corner.fusion, &m).is_ok());
  Registrar reg(RegistrationConfig{});
  const Pose initial = perturb(truth, {0.06, -0.04, 0.03}, {0, 0, 1}, 3.0);
  const RegistrationResult r = reg.track(m, corner.map, initial);
  EXPECT_LT((r.T_world_cam.translation() - truth.translation()).norm(), 2e-3);
  EXPECT_LT(rotation_deg(r.T_world_cam, truth), 0.1);
}

TEST(Registration, AlignsToAModelRenderedFromAnotherPose) {
  // The fusion daemon may align a frame to the model rendered for the frame before: associations
  // then go through that model's camera. 1.5 cm and 1 degree away, the pose is still recovered.
  CornerMap corner;
  const Pose before = test::look_at({1.8, 1.9, 1.5}, {0.3, 0.3, 0.3});
  const Pose truth = perturb(before, {0.012, -0.008, 0.004}, {0.2, 1, 0.1}, 1.0);
  MeasurementImage m_before, m;
  ASSERT_TRUE(backproject(test::render_corner(before), corner.sensor, corner.fusion, &m_before).is_ok());
  ASSERT_TRUE(backproject(test::render_corner(truth), corner.sensor, corner.fusion, &m).is_ok());
  Registrar reg(RegistrationConfig{});
  ASSERT_TRUE(reg.refine(m_before, corner.map, before).converged);
  const SurfaceView model = reg.model();
  ASSERT_FALSE(model.empty());
  EXPECT_TRUE(model.T_world_cam.isApprox(before));

  const Pose initial = perturb(truth, {0.01, 0.005, -0.005}, {1, 0, 0.3}, 0.5);
  const RegistrationResult r = reg.refine(m, model, initial);
  ASSERT_TRUE(r.converged);
  EXPECT_LT((r.T_world_cam.translation() - truth.translation()).norm(), 1e-3);
  EXPECT_LT(rotation_deg(r.T_world_cam, truth), 0.05);

  // An empty model: no registration, the initial pose stays.
  const RegistrationResult none = reg.refine(m, SurfaceView{}, initial);
  EXPECT_FALSE(none.converged);
  EXPECT_TRUE(none.T_world_cam.isApprox(initial));
}

TEST(Registration, AViewOfOneWallMovesThePoseOnlyWhereTheWallConstrainsIt) {
  // A plane 2 m in front of the camera fixes the distance to it and the two tilts; it says nothing
  // about sliding along it or turning about its normal. Every frame carries +-2 mm of noise, which
  // tilts the normals a little and so gives those directions a little information and a random
  // pull. With degenerate_ratio the slide keeps its initial value; the distance is still corrected.
  SensorModelConfig sensor;
  FusionConfig fusion;
  PointMap map(0.5);
  Fuser fuser(sensor, fusion);
  MeasurementImage m;
  uint32_t state = 12345;  // a fixed LCG: the same noise on every run
  auto noisy_plane = [&] {
    Frame f = test::render_plane(Pose::Identity(), Eigen::Vector3d::UnitZ(), 2.0);
    for (float& z : f.depth.depth_m) {
      state = state * 1664525u + 1013904223u;
      z += 2e-3f * (static_cast<float>(state >> 8) / static_cast<float>(1u << 24) * 2.0f - 1.0f);
    }
    return f;
  };
  for (uint32_t id = 1; id <= 3; ++id) {
    ASSERT_TRUE(backproject(noisy_plane(), sensor, fusion, &m).is_ok());
    fuser.fuse(m, nullptr, Pose::Identity(), id, &map);
  }
  ASSERT_TRUE(backproject(noisy_plane(), sensor, fusion, &m).is_ok());
  const Pose initial = perturb(Pose::Identity(), {0.01, -0.01, 0.01}, {0, 0, 1}, 0.5);

  for (const double ratio : {0.0, 0.005}) {
    SCOPED_TRACE("degenerate_ratio " + std::to_string(ratio));
    RegistrationConfig config;
    config.degenerate_ratio = ratio;
    const RegistrationResult r = Registrar(config).refine(m, map, initial);
    ASSERT_TRUE(r.converged);
    EXPECT_LT(std::abs(r.T_world_cam.translation().z()), 1e-3);  // 1 cm off the plane: corrected
    const double slide_m =
        (r.T_world_cam.translation() - initial.translation()).head<2>().norm();
    const double turn_deg = std::abs(rotation_deg(r.T_world_cam, Pose::Identity()) - 0.5);
    if (ratio > 0) {
      EXPECT_LT(slide_m, 1e-4);
      EXPECT_LT(turn_deg, 0.01);
    } else {
      // Without it the noise moves the pose along the wall (the reason for the option).
      EXPECT_GT(slide_m + turn_deg * 1e-2, 1e-3);
    }
    std::printf("degenerate_ratio %.3f: slide %.2f mm, turn %.3f deg\n", ratio, slide_m * 1e3,
                turn_deg);
  }
}

TEST(Registration, TrackingHoldsWhatAWallDoesNotConstrainAtTheGivenPose) {
  // The camera stands still before a wall; the track starts 3 cm along the wall and 1 degree about
  // its normal away. The wall corrects the distance and the tilts only; the directions it does not
  // constrain keep the start's value, or that of the pose they are held at. (The pipeline holds
  // them at its start, the motion model's prediction: Sequence.AlongAWall... in test_pipeline.)
  SensorModelConfig sensor;
  FusionConfig fusion;
  PointMap map(0.5);
  Fuser fuser(sensor, fusion);
  MeasurementImage m;
  for (uint32_t id = 1; id <= 3; ++id) {
    ASSERT_TRUE(backproject(test::render_plane(Pose::Identity(), Eigen::Vector3d::UnitZ(), 2.0),
                            sensor, fusion, &m).is_ok());
    fuser.fuse(m, nullptr, Pose::Identity(), id, &map);
  }
  const Pose last = Pose::Identity();
  const Pose predicted = perturb(last, {0.03, 0.0, 0.01}, {0, 0, 1}, 1.0);
  RegistrationConfig config;
  const RegistrationResult carried = Registrar(config).track(m, map, predicted);
  const RegistrationResult held = Registrar(config).track(m, map, predicted, last);
  for (const RegistrationResult* r : {&carried, &held}) {
    ASSERT_TRUE(r->converged);
    EXPECT_LT(std::abs(r->T_world_cam.translation().z()), 1e-3);  // the distance: corrected
    EXPECT_LT(r->conditioning, config.tracking_degenerate_ratio);
  }
  EXPECT_NEAR(carried.T_world_cam.translation().x(), 0.03, 1e-3);
  EXPECT_LT(held.T_world_cam.translation().head<2>().norm(), 1e-4);
  EXPECT_LT(rotation_deg(held.T_world_cam, last), 0.01);
  // Where ICP could not tell, the frame is no more than uncertain.
  EXPECT_EQ(classify_tracking(held, config), TrackingState::kUncertain);
}

TEST(Registration, EmptyMapKeepsThePose) {
  PointMap empty(0.5);
  const Pose truth = test::look_at({1.8, 1.9, 1.5}, {0.3, 0.3, 0.3});
  MeasurementImage m;
  ASSERT_TRUE(backproject(test::render_corner(truth), SensorModelConfig{}, FusionConfig{}, &m).is_ok());
  Registrar reg(RegistrationConfig{});
  const RegistrationResult r = reg.refine(m, empty, truth);
  EXPECT_FALSE(r.converged);
  EXPECT_TRUE(r.T_world_cam.isApprox(truth));
}

TEST(Registration, FusionAndRegistrationDoNotDependOnTheThreadCount) {
  // Rendering, fusion and ICP split their work in two halves whether or not a second thread runs
  // them: the map and the refined pose must come out the same bit for bit.
  CornerMap one(1, true), two(2, true);
  const PointArrays a = one.map.gather(), b = two.map.gather();
  ASSERT_GT(a.size(), 100000u);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(0, std::memcmp(a.position_m.data(), b.position_m.data(), a.size() * sizeof(a.position_m[0])));
  EXPECT_EQ(0, std::memcmp(a.state.data(), b.state.data(), a.size() * sizeof(a.state[0])));

  const Pose truth = test::look_at({1.8, 1.9, 1.5}, {0.3, 0.3, 0.3});
  MeasurementImage m;
  ASSERT_TRUE(backproject(test::render_corner(truth), one.sensor, one.fusion, &m).is_ok());
  const Pose initial = perturb(truth, {0.015, -0.01, 0.01}, {0.3, 1, -0.2}, 1.0);
  RegistrationConfig rc;
  rc.threads = 1;
  const RegistrationResult r1 = Registrar(rc).refine(m, one.map, initial);
  rc.threads = 2;
  const RegistrationResult r2 = Registrar(rc).refine(m, one.map, initial);
  ASSERT_TRUE(r1.converged);
  EXPECT_TRUE(r1.T_world_cam.matrix() == r2.T_world_cam.matrix());
  EXPECT_EQ(r1.correspondences, r2.correspondences);
}

namespace {

// Blocky holes like a real depth camera's (dark, shiny or distant surfaces): 6x6-pixel blocks, of
// which `dropped_tenths` in ten lose their depth, chosen by a fixed hash.
void punch_holes(Frame* f, int dropped_tenths) {
  for (int v = 0; v < f->depth.height; ++v)
    for (int u = 0; u < f->depth.width; ++u) {
      const uint32_t h = (static_cast<uint32_t>(u / 6) * 73856093u) ^
                         (static_cast<uint32_t>(v / 6) * 19349663u);
      if (static_cast<int>((h >> 7) % 10) < dropped_tenths) f->depth.at(u, v) = 0.0f;
    }
}

}  // namespace

TEST(Registration, TrackingCoarseLevelsRunOnAFrameWithHoles) {
  // With 70 % of the depth missing, the coarsest level (every 16th pixel) finds ~300 pairs, fewer
  // than registration.min_correspondences (500), which holds at the finest level. The coarse levels
  // must scale it down with their sampling, or only the finer gates (10 and 5 cm) are left for a
  // turn that moves the far wall by ~20 cm: the pose then slid 6-7 cm off, or stayed 7 degrees off
  // (the first lost frame of TUM fr1/xyz tracking had an 8-degree turn). Beyond about 8 degrees
  // (7.5-8.5, as the map's points fall) this frame converges to a wrong pose even so.
  CornerMap corner;
  const Pose truth = test::look_at({1.8, 1.9, 1.5}, {0.3, 0.3, 0.3});
  Frame f = test::render_corner(truth);
  punch_holes(&f, 7);
  MeasurementImage m;
  ASSERT_TRUE(backproject(f, corner.sensor, corner.fusion, &m).is_ok());
  ASSERT_LT(m.valid_count(), f.depth.depth_m.size() * 4 / 10);
  for (double deg : {5.0, 7.0}) {
    Pose D = Pose::Identity();  // about the camera, like a hand-held turn
    D.linear() = Eigen::AngleAxisd(deg * M_PI / 180.0, Eigen::Vector3d(0.3, 1, 0.1).normalized())
                     .toRotationMatrix();
    D.translation() = Eigen::Vector3d(0.03, -0.02, 0.02);
    Registrar reg(RegistrationConfig{});
    const RegistrationResult r = reg.track(m, corner.map, truth * D);
    ASSERT_TRUE(r.converged) << deg << " degrees";
    EXPECT_LT((r.T_world_cam.translation() - truth.translation()).norm(), 2e-3)
        << deg << " degrees";
    EXPECT_LT(rotation_deg(r.T_world_cam, truth), 0.1) << deg << " degrees";
  }
}

// Issue 19, every 3rd frame of TUM fr1/xyz (docs/history/results-sessions-1-33.md, "Issue 19 at
// s28-track"): correctly placed frames of a real Kinect agree with the map on ~84 % of their
// samples that land on it (5 % of them under 73 %), synthetic ones on 99.7 %. Under the absolute
// rule (0.9) seven frames in a row that looked into unmapped space (fitness 0.41, model fitness
// 0.87) were lost although tracked, and the relocaliser took a candidate 12 cm off (fitness 0.53,
// model fitness 0.63, residual 10 mm) as "tracked".
TEST(Registration, ModelFitnessIsJudgedAgainstWhatTrackedFramesScore) {
  RegistrationConfig c;
  RegistrationResult exploring;
  exploring.converged = true;
  exploring.fitness = 0.41;
  exploring.model_fitness = 0.87;
  exploring.rmse_m = 0.003;
  exploring.conditioning = 0.013;
  const double real = 0.84, synthetic = 0.997;
  EXPECT_EQ(classify_tracking(exploring, c, real), TrackingState::kUncertain);
  EXPECT_EQ(classify_tracking(exploring, c, synthetic), TrackingState::kLost);
  EXPECT_EQ(classify_tracking(exploring, c), TrackingState::kLost);  // no tracked frame yet

  // The wrong relocalisation: enough pairs to pass as tracked, but where the map has a surface the
  // frame disagrees with it more than any tracked frame does.
  RegistrationResult wrong;
  wrong.converged = true;
  wrong.fitness = 0.53;
  wrong.model_fitness = 0.63;
  wrong.rmse_m = 0.010;
  wrong.conditioning = 0.0031;
  EXPECT_EQ(classify_tracking(wrong, c, real), TrackingState::kTracked);
  EXPECT_FALSE(relocalisation_verified(wrong, c, real));
  // The synthetic loop's wrap, found again from a keyframe: taken.
  RegistrationResult found = exploring;
  found.fitness = 0.9;
  found.model_fitness = 0.995;
  EXPECT_TRUE(relocalisation_verified(found, c, synthetic));
  // A real frame relocalised where it is scores as tracked frames do.
  found.model_fitness = 0.85;
  EXPECT_TRUE(relocalisation_verified(found, c, real));
}
