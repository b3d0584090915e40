// The pre-filter against analytic expectations: d_r(z) on a plane, a flying pixel, planes kept.
#include <gtest/gtest.h>

#include "core_test_util.hpp"
#include "depthfuse/measurement.hpp"

using namespace depthfuse;

namespace {

MeasurementImage measure(const Frame& f) {
  MeasurementImage m;
  SensorModelConfig s;
  s.max_depth_m = 10;
  EXPECT_TRUE(backproject(f, s, FusionConfig{}, &m).is_ok());
  return m;
}

Frame frontal_plane(double z_m) {
  return test::render_plane(Pose::Identity(), Eigen::Vector3d::UnitZ(), z_m);
}

}  // namespace

TEST(Prefilter, ReferenceDistanceIsPixelPitchForPinhole) {
  // On a fronto-parallel plane the 4 nearest neighbours are the 4-connected pixels, 1/f away at 1 m.
  const CameraIntrinsics K = CameraIntrinsics::kinect_v2();
  EXPECT_NEAR(reference_knn_distance_per_m(K, 4, 1), 1.0 / K.fx, 1e-3 / K.fx);
  // The 5th neighbour is a diagonal one: sqrt(2) pixels.
  EXPECT_NEAR(reference_knn_distance_per_m(K, 5, 1), std::sqrt(2.0) / K.fx, 1e-3 / K.fx);
}

TEST(Prefilter, KeepsPlaneRemovesFlyingPixel) {
  Frame f = frontal_plane(2.0);
  const int u = 200, v = 150;
  f.depth.at(u, v) = 1.6f;  // a flying pixel between the plane and the camera
  MeasurementImage m = measure(f);
  const size_t valid_before = m.valid_count();
  PrefilterConfig c;
  const size_t removed = prefilter(c, &m);
  EXPECT_FALSE(m.valid[v * m.width + u]) << "flying pixel kept";
  // Its neighbours on the plane stay, and so does the plane (only the 4 image corners, which have
  // just 3 neighbours, go as well).
  for (int dv = -1; dv <= 1; ++dv)
    for (int du = -1; du <= 1; ++du)
      if (du || dv) {
        EXPECT_TRUE(m.valid[(v + dv) * m.width + (u + du)]);
      }
  EXPECT_LE(removed, 5u);
  EXPECT_EQ(m.valid_count(), valid_before - removed);
}

TEST(Prefilter, KeepsModerateIncidenceRemovesGrazing) {
  // A plane tilted about the y axis, looked at along the optical axis: at 30 degrees incidence
  // the spacing between neighbours is 1/cos(30) = 1.15 pixel pitches and the points stay; at 70
  // degrees it is 2.9 > gamma = 1.83 and the paper's rule drops them. Checked near the image centre,
  // where the incidence angle is the tilt.
  auto slanted = [](double deg) {
    const double a = deg * M_PI / 180.0;
    const Eigen::Vector3d n(std::sin(a), 0, -std::cos(a));
    return test::render_plane(Pose::Identity(), n, n.dot(Eigen::Vector3d(0, 0, 2.0)));
  };
  auto centre_kept_fraction = [](const MeasurementImage& m) {
    int kept = 0, total = 0;
    for (int v = 200; v < 224; ++v)
      for (int u = 240; u < 270; ++u, ++total) kept += m.valid[v * m.width + u];
    return static_cast<double>(kept) / total;
  };
  MeasurementImage m30 = measure(slanted(30));
  prefilter(PrefilterConfig{}, &m30);
  EXPECT_EQ(centre_kept_fraction(m30), 1.0);
  MeasurementImage m70 = measure(slanted(70));
  prefilter(PrefilterConfig{}, &m70);
  EXPECT_EQ(centre_kept_fraction(m70), 0.0);
}

TEST(Prefilter, DisabledDoesNothing) {
  Frame f = frontal_plane(2.0);
  f.depth.at(10, 10) = 1.0f;
  MeasurementImage m = measure(f);
  PrefilterConfig c;
  c.enabled = false;
  EXPECT_EQ(prefilter(c, &m), 0u);
}

TEST(Backproject, RejectsSizeMismatch) {
  Frame f = frontal_plane(2.0);
  f.intrinsics.width = 640;
  MeasurementImage m;
  const Status s = backproject(f, SensorModelConfig{}, FusionConfig{}, &m);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("512x424"), std::string::npos) << s.message();
}

TEST(Backproject, NormalsFaceTheCamera) {
  MeasurementImage m = measure(frontal_plane(2.0));
  const size_t i = 212 * m.width + 256;
  EXPECT_NEAR(m.nz[i], -1.0f, 1e-4f);
  EXPECT_NEAR(m.z[i], 2.0f, 1e-6f);
}

TEST(Backproject, NormalsOfTheCornerArePlaneNormalsAndNoneWithoutNeighbours) {
  // Three orthogonal planes, seen so that the image holds all three and their edges, with a hole
  // punched in: where the four neighbours at the normal radius lie on the pixel's own plane, the
  // normal is that plane's normal turned towards the camera. Each side of a pixel needs one
  // usable neighbour; a lone pixel (its neighbours all missing) has none.
  const Pose T = test::look_at({2.0, 1.8, 1.5}, {0.2, 0.2, 0.3});
  Frame f = test::render_corner(T);
  const int hu = 300, hv = 150, r = FusionConfig{}.normal_radius_px;
  for (int v = hv - r; v <= hv + r; ++v)
    for (int u = hu - r; u <= hu + r; ++u)
      if (u != hu || v != hv) f.depth.at(u, v) = 0.0f;  // leaves (hu, hv) alone in a hole
  MeasurementImage m = measure(f);
  const Eigen::Matrix3d R = T.linear();
  int checked = 0;
  for (int v = 0; v < m.height; ++v)
    for (int u = 0; u < m.width; ++u) {
      const size_t i = static_cast<size_t>(v) * m.width + u;
      if (!m.valid[i]) continue;
      const Eigen::Vector3d p = T * Eigen::Vector3d(m.x[i], m.y[i], m.z[i]);
      int axis = 0;  // the plane the point lies on: its smallest coordinate
      for (int a = 1; a < 3; ++a) if (std::abs(p[a]) < std::abs(p[axis])) axis = a;
      bool same_plane = u >= r && v >= r && u + r < m.width && v + r < m.height;
      for (int d : {-r, r}) {
        for (size_t j : {i + d, i + static_cast<size_t>(d) * m.width}) {
          if (!same_plane || !m.valid[j]) { same_plane = false; break; }
          const Eigen::Vector3d q = T * Eigen::Vector3d(m.x[j], m.y[j], m.z[j]);
          same_plane = std::abs(q[axis]) < 1e-4;
        }
      }
      if (!same_plane) continue;
      const Eigen::Vector3d n = R * Eigen::Vector3d(m.nx[i], m.ny[i], m.nz[i]);
      ASSERT_NEAR(n[axis], 1.0, 1e-3) << "pixel " << u << ", " << v;  // the planes face +x, +y, +z
      ++checked;
    }
  EXPECT_GT(checked, 100000);
  const size_t lone = static_cast<size_t>(hv) * m.width + hu;
  ASSERT_TRUE(m.valid[lone]);
  EXPECT_EQ(m.nx[lone], 0.0f);
  EXPECT_EQ(m.ny[lone], 0.0f);
  EXPECT_EQ(m.nz[lone], 0.0f);
}

TEST(Prefilter, TwoThreadsGiveTheSameMeasurements) {
  // The corner, with a speck of flying pixels and holes scattered over it (some on the rows where
  // the image splits in two halves).
  Frame f = test::render_corner(test::look_at({2.0, 2.0, 1.6}, {0.0, 0.0, 0.8}));
  for (size_t i = 0; i < f.depth.depth_m.size(); i += 97) f.depth.depth_m[i] *= (i % 2) ? 1.3f : 0.0f;
  SensorModelConfig s;
  MeasurementImage one, two;
  FusionConfig fc;
  fc.threads = 1;
  ASSERT_TRUE(backproject(f, s, fc, &one).is_ok());
  fc.threads = 2;
  ASSERT_TRUE(backproject(f, s, fc, &two).is_ok());
  const size_t removed_one = prefilter(PrefilterConfig{}, &one, 1);
  const size_t removed_two = prefilter(PrefilterConfig{}, &two, 2);
  EXPECT_GT(removed_one, 100u);
  EXPECT_EQ(removed_one, removed_two);
  EXPECT_EQ(one.valid, two.valid);
  for (auto member : {&MeasurementImage::x, &MeasurementImage::y, &MeasurementImage::z,
                      &MeasurementImage::nx, &MeasurementImage::ny, &MeasurementImage::nz})
    EXPECT_TRUE(one.*member == two.*member);
}

// A rolling-shutter camera moving along its optical axis towards a wall: each row is taken from
// another place, so the wall's depth changes from row to row by the distance travelled. Undone
// with the camera's velocity, every row sees the wall from where the middle row was taken.
TEST(RollingShutter, UndoneWithTheVelocityAFrontalWallIsFlat) {
  CameraIntrinsics K = CameraIntrinsics::kinect_v2();
  K.row_readout_s = 0.03;
  const double wall_m = 2.0, speed_m_s = 0.5;
  Frame f;
  f.intrinsics = K;
  f.depth = DepthImage(K.width, K.height);
  for (int v = 0; v < K.height; ++v) {
    const double dt_s = ((v + 0.5) / K.height - 0.5) * K.row_readout_s;
    Pose T = Pose::Identity();
    T.translation() = Eigen::Vector3d(0, 0, speed_m_s * dt_s);
    const Frame row = test::render_plane(T, Eigen::Vector3d::UnitZ(), wall_m, K);
    for (int u = 0; u < K.width; ++u) f.depth.at(u, v) = row.depth.at(u, v);
  }
  // As taken: the top row 7.5 mm farther than the wall, the bottom one 7.5 mm nearer.
  EXPECT_NEAR(f.depth.at(K.width / 2, 0), wall_m + speed_m_s * K.row_readout_s / 2, 1e-4);
  EXPECT_NEAR(f.depth.at(K.width / 2, K.height - 1), wall_m - speed_m_s * K.row_readout_s / 2, 1e-4);

  CameraVelocity velocity;
  velocity.v_cam_m_s = Eigen::Vector3d(0, 0, speed_m_s);
  DepthImage undone;
  ASSERT_TRUE(undo_rolling_shutter(f, velocity, &undone));
  ASSERT_EQ(undone.width, K.width);
  // Inside the image; at its border a pixel whose source lies outside (the wall grows as the
  // camera nears it: by up to a pixel here) has no depth.
  for (int v = 4; v < K.height - 4; v += 7)
    for (int u = 4; u < K.width - 4; u += 7)
      ASSERT_NEAR(undone.at(u, v), wall_m, 1e-5) << u << "," << v;

  // A global shutter, or no motion: nothing to undo.
  f.intrinsics.row_readout_s = 0.0;
  EXPECT_FALSE(undo_rolling_shutter(f, velocity, &undone));
  f.intrinsics.row_readout_s = 0.03;
  EXPECT_FALSE(undo_rolling_shutter(f, CameraVelocity{}, &undone));
}

TEST(RollingShutter, VelocitiesFromNeighbouringPosesInTheCameraFrame) {
  // A camera turned by 90 degrees about z, moving along world x at 0.3 m/s and turning about world
  // z at 0.6 rad/s: in its own frame it moves along -y and turns about z.
  std::vector<Frame> frames(3);
  std::vector<Pose> poses(3);
  for (int i = 0; i < 3; ++i) {
    frames[i].utime = 1000000 + i * 33000;
    const double t_s = i * 0.033;
    poses[i] = Pose::Identity();
    poses[i].linear() = Eigen::AngleAxisd(M_PI / 2 + 0.6 * t_s, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    poses[i].translation() = Eigen::Vector3d(0.3 * t_s, 0, 0);
  }
  const std::vector<CameraVelocity> vel = camera_velocities(frames, poses);
  ASSERT_EQ(vel.size(), 3u);
  EXPECT_NEAR(vel[1].omega_cam_rad_s.z(), 0.6, 1e-6);
  EXPECT_NEAR(vel[1].omega_cam_rad_s.head<2>().norm(), 0.0, 1e-9);
  // R^T (0.3, 0, 0) with R about z by 90 degrees plus a little: (0.3 cos, -0.3 sin, 0).
  const double a = M_PI / 2 + 0.6 * 0.033;
  EXPECT_NEAR(vel[1].v_cam_m_s.x(), 0.3 * std::cos(a), 1e-6);
  EXPECT_NEAR(vel[1].v_cam_m_s.y(), -0.3 * std::sin(a), 1e-6);
  // The ends are one-sided; one frame alone has no velocity.
  EXPECT_NEAR(vel[0].v_cam_m_s.norm(), 0.3, 1e-6);
  EXPECT_TRUE(camera_velocities({frames[0]}, {poses[0]})[0].v_cam_m_s.isZero());
}
