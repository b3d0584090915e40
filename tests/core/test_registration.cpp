// Re-registration recovers a known offset on the concave corner.
#include <gtest/gtest.h>

#include "analytic.hpp"
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

struct CornerMap {
  SensorModelConfig sensor;
  FusionConfig fusion;
  PointMap map{0.5};
  CornerMap() {
    Fuser fuser(sensor, fusion);
    MeasurementImage m;
    uint32_t id = 1;
    for (const Eigen::Vector3d& eye : {Eigen::Vector3d(2.0, 1.6, 1.4), Eigen::Vector3d(1.5, 2.1, 1.3),
                                      Eigen::Vector3d(2.2, 2.2, 1.6)}) {
      const Pose T = test::look_at(eye, Eigen::Vector3d(0.3, 0.3, 0.3));
      EXPECT_TRUE(backproject(test::render_corner(T), sensor, fusion, &m).is_ok());
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
