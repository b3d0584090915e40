// The photometric term of tracking: its gradient against finite differences, and what it adds.
#include <gtest/gtest.h>

#include <cmath>

#include "core_test_util.hpp"
#include "depthfuse/measurement.hpp"
#include "photometric.hpp"

using namespace depthfuse;

namespace {

// A smooth texture, so that central differences of the image (and of its pyramid levels) are its
// derivative within a few percent.
float texture(float u, float v) { return 0.5f + 0.3f * std::sin(u / 40.0f) * std::cos(v / 50.0f); }

ColorImage textured(int width, int height) {
  ColorImage c;
  c.width = width;
  c.height = height;
  c.rgb.resize(static_cast<size_t>(width) * height * 3);
  for (int v = 0; v < height; ++v)
    for (int u = 0; u < width; ++u)
      for (int k = 0; k < 3; ++k)
        c.rgb[3 * (static_cast<size_t>(v) * width + u) + k] =
            static_cast<uint8_t>(std::lround(255.0f * texture(u, v)));
  return c;
}

// The pose moved by a twist xi (rotation first) about the centre c, on the left in the world frame:
// the update Registrar's ICP applies.
Pose apply_twist(const Pose& T, const Eigen::Matrix<double, 6, 1>& xi, const Eigen::Vector3d& c) {
  Pose D = Pose::Identity();
  const Eigen::Vector3d w = xi.head<3>();
  if (w.norm() > 0) D.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
  D.translation() = xi.tail<3>();
  Pose Tc = Pose::Identity();
  Tc.translation() = c;
  return Tc * D * Tc.inverse() * T;
}

}  // namespace

// The kernel's gradient with respect to the world point, against central differences of its
// residual, on every level of the pyramid.
TEST(Photometric, ResidualGradientMatchesFiniteDifferences) {
  const CameraIntrinsics K = CameraIntrinsics::kinect_v2();
  for (int level = 0; level < 3; ++level) {
    // Level l of the same texture, sampled at the level's pixel centres.
    IntensityLevel L;
    L.width = K.width >> level;
    L.height = K.height >> level;
    L.intensity.resize(static_cast<size_t>(L.width) * L.height);
    const float s = static_cast<float>(1 << level);
    for (int v = 0; v < L.height; ++v)
      for (int u = 0; u < L.width; ++u)
        L.intensity[static_cast<size_t>(v) * L.width + u] = texture((u + 0.5f) * s - 0.5f, (v + 0.5f) * s - 0.5f);
    compute_gradients(&L);
    const Pose T_world_ref = test::look_at({0.2, -0.1, 0.0}, {0.5, 0.3, 2.0});
    const Pose T_ref_world = T_world_ref.inverse();
    const PhotometricReference ref{&L, static_cast<float>(K.fx), static_cast<float>(K.fy),
                                   static_cast<float>(K.cx), static_cast<float>(K.cy), 1.0f / s,
                                   T_ref_world.linear().cast<float>(),
                                   T_ref_world.translation().cast<float>()};
    int checked = 0;
    for (const Eigen::Vector3f& p_ref : {Eigen::Vector3f(0.1f, 0.05f, 1.2f), Eigen::Vector3f(-0.4f, 0.2f, 2.0f),
                                        Eigen::Vector3f(0.3f, -0.25f, 1.6f)}) {
      const Eigen::Vector3f p_w = (T_world_ref * p_ref.cast<double>()).cast<float>();
      float r;
      Eigen::Vector3f g, q;
      ASSERT_TRUE(photometric_residual(ref, p_w, 0.3f, &r, &g, &q));
      EXPECT_LT((q - p_ref).norm(), 1e-5f);
      const float h = 2e-4f;  // m: a fraction of a pixel at these depths
      for (int a = 0; a < 3; ++a) {
        Eigen::Vector3f d = Eigen::Vector3f::Zero();
        d[a] = h;
        float rp, rm;
        Eigen::Vector3f unused_g, unused_q;
        ASSERT_TRUE(photometric_residual(ref, p_w + d, 0.3f, &rp, &unused_g, &unused_q));
        ASSERT_TRUE(photometric_residual(ref, p_w - d, 0.3f, &rm, &unused_g, &unused_q));
        const float fd = (rp - rm) / (2 * h);
        // Central differences of the sampled texture are its derivative within a few percent.
        EXPECT_NEAR(g[a], fd, 0.08f * g.norm() + 1e-3f) << "level " << level << " axis " << a;
      }
      ++checked;
    }
    EXPECT_EQ(checked, 3);
  }
}

// The term's gradient in the twist ICP steps in (b = sum J r, H's diagonal sum J^2) against central
// differences of its cost 0.5 sum r^2 over a textured plane, on the finest and the coarsest level.
TEST(Photometric, TwistGradientMatchesFiniteDifferencesOfTheCost) {
  RegistrationConfig config;
  config.photometric_weight = 1.0;
  config.tracking_levels = 3;
  PhotometricTerm term(config);
  const Pose T_ref = test::look_at({0.0, 0.0, 0.0}, {0.1, 0.05, 1.0}, Eigen::Vector3d::UnitY());
  const Frame f = test::render_plane(T_ref, Eigen::Vector3d(0.05, -0.1, -1.0).normalized(), -1.5);
  const ColorImage color = textured(f.depth.width, f.depth.height);
  MeasurementImage m;
  ASSERT_TRUE(backproject(f, SensorModelConfig{}, FusionConfig{}, &m).is_ok());
  term.set_frame(color, m);
  term.keep_frame_as_reference(m, T_ref);
  EXPECT_FALSE(term.ready());  // no frame to track yet
  // The frame tracked: its pixels away from the border, so that no pair leaves the reference's
  // image between the finite differences' poses.
  MeasurementImage tracked = m;
  for (int v = 0; v < m.height; ++v)
    for (int u = 0; u < m.width; ++u)
      if (u < 40 || v < 40 || u >= m.width - 40 || v >= m.height - 40)
        tracked.valid[static_cast<size_t>(v) * m.width + u] = 0;
  term.set_frame(color, tracked);
  ASSERT_TRUE(term.ready());

  // The same frame, half a centimetre and a fraction of a degree from where it was taken.
  Eigen::Matrix<double, 6, 1> off;
  off << 0.002, -0.003, 0.001, 0.005, -0.003, 0.002;
  const Eigen::Vector3d c = T_ref.translation() + Eigen::Vector3d(0.01, 0.0, 0.0);
  const Pose T = apply_twist(T_ref, off, c);
  const Eigen::Vector3f centre = c.cast<float>();
  for (int level : {0, 2}) {
    const PhotometricSums s = term.sums(tracked, T, centre, level, 2, 0.1f);
    ASSERT_GT(s.pairs, 1000u);
    const double eps = 1e-5;
    for (int a = 0; a < 6; ++a) {
      Eigen::Matrix<double, 6, 1> d = Eigen::Matrix<double, 6, 1>::Zero();
      d[a] = eps;
      const PhotometricSums plus = term.sums(tracked, apply_twist(T, d, c), centre, level, 2, 0.1f);
      const PhotometricSums minus = term.sums(tracked, apply_twist(T, -d, c), centre, level, 2, 0.1f);
      ASSERT_EQ(plus.pairs, s.pairs);
      ASSERT_EQ(minus.pairs, s.pairs);
      const double fd = 0.25 * (plus.sq_residual - minus.sq_residual) / eps;
      EXPECT_NEAR(s.b[a], fd, 0.05 * s.b.norm()) << "level " << level << " direction " << a;
    }
  }
}

// Without colour, with colour of another size, or with the weight 0, the term adds nothing.
TEST(Photometric, NoTermWithoutUsableColourOrWeight) {
  const Pose T = test::look_at({0.0, 0.0, 0.0}, {0.0, 0.0, 1.0}, Eigen::Vector3d::UnitY());
  const Frame f = test::render_plane(T, Eigen::Vector3d(0, 0, -1), -1.5);
  MeasurementImage m;
  ASSERT_TRUE(backproject(f, SensorModelConfig{}, FusionConfig{}, &m).is_ok());
  RegistrationConfig on;
  on.photometric_weight = 1.0;
  for (const ColorImage& color : {ColorImage{}, textured(f.depth.width / 2, f.depth.height / 2)}) {
    PhotometricTerm term(on);
    term.set_frame(color, m);
    term.keep_frame_as_reference(m, T);
    term.set_frame(color, m);
    EXPECT_FALSE(term.ready());
  }
  RegistrationConfig zero;
  zero.photometric_weight = 0.0;
  PhotometricTerm off(zero);
  const ColorImage color = textured(f.depth.width, f.depth.height);
  off.set_frame(color, m);
  off.keep_frame_as_reference(m, T);
  off.set_frame(color, m);
  EXPECT_FALSE(off.ready());
}
