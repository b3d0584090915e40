#include "photometric.hpp"

#include <cmath>

#include "model_projection.hpp"
#include "parallel.hpp"

namespace depthfuse {

namespace {

// Scale of the Huber loss on intensity differences (0..1). Our choice: about ten times a camera's
// pixel noise; larger differences are occlusions, specularities or exposure changes, and count
// as a constant pull, not a quadratic one.
constexpr float kIntensityHuber = 0.1f;

}  // namespace

void PhotometricSums::merge(const PhotometricSums& o) {
  H += o.H;
  b += o.b;
  sq_residual += o.sq_residual;
  pairs += o.pairs;
}

PhotometricTerm::PhotometricTerm(const RegistrationConfig& config)
    : weight_(config.photometric_weight),
      levels_(std::max({1, config.tracking_levels, config.tracking_levels_without_motion})),
      threads_(config.threads) {}

void PhotometricTerm::set_frame(const ColorImage& color, const MeasurementImage& m) {
  has_frame_ = weight_ > 0 && !color.empty() && color.width == m.width &&
               color.height == m.height &&
               color.rgb.size() == static_cast<size_t>(color.width) * color.height * 3;
  if (has_frame_) build_intensity_pyramid(color, levels_, &frame_);
}

void PhotometricTerm::keep_frame_as_reference(const MeasurementImage& m, const Pose& T_world_cam) {
  has_reference_ = has_frame_;
  if (!has_frame_) return;
  std::swap(frame_, reference_);
  has_frame_ = false;  // its pyramid is the reference's now
  for (IntensityLevel& level : reference_) compute_gradients(&level);
  reference_K_ = m.intrinsics;
  reference_depth_m_.resize(m.pixel_count());
  for (size_t i = 0; i < m.pixel_count(); ++i) reference_depth_m_[i] = m.valid[i] ? m.z[i] : 0.0f;
  T_ref_world_ = T_world_cam.inverse();
}

void PhotometricTerm::clear() { has_reference_ = false; }

bool PhotometricTerm::ready() const { return has_frame_ && has_reference_; }

PhotometricSums PhotometricTerm::sums(const MeasurementImage& m, const Pose& T_world_cam,
                                      const Eigen::Vector3f& centre, int level, int step,
                                      float gate_m) const {
  PhotometricSums total;
  if (!ready()) return total;
  level = std::min(level, static_cast<int>(reference_.size()) - 1);
  const PhotometricReference ref{&reference_[level],
                                 static_cast<float>(reference_K_.fx),
                                 static_cast<float>(reference_K_.fy),
                                 static_cast<float>(reference_K_.cx),
                                 static_cast<float>(reference_K_.cy),
                                 1.0f / static_cast<float>(1 << level),
                                 T_ref_world_.linear().cast<float>(),
                                 T_ref_world_.translation().cast<float>()};
  const IntensityLevel& own = frame_[level];
  const Eigen::Matrix3f R = T_world_cam.linear().cast<float>();
  const Eigen::Vector3f t = T_world_cam.translation().cast<float>();
  const float fx = ref.fx, fy = ref.fy, cx = ref.cx, cy = ref.cy;
  const int rw = reference_K_.width, rh = reference_K_.height;
  step = std::max(1, step);

  auto pass = [&](int v_begin, int v_end, PhotometricSums* out) {
    for (int v = v_begin; v < v_end; v += step) {
      // The frame's own intensity at this pixel, on the level's coarser grid.
      const float* own_row =
          own.intensity.data() + static_cast<size_t>(std::min(v >> level, own.height - 1)) * own.width;
      for (int u = 0; u < m.width; u += step) {
        const size_t i = static_cast<size_t>(v) * m.width + u;
        if (!m.valid[i]) continue;
        const Eigen::Vector3f p_w = R * Eigen::Vector3f(m.x[i], m.y[i], m.z[i]) + t;
        float r;
        Eigen::Vector3f g, p_ref;
        if (!photometric_residual(ref, p_w, own_row[std::min(u >> level, own.width - 1)], &r, &g, &p_ref))
          continue;
        // Seen by the reference? Its depth where the point lands must agree.
        const uint32_t px = pixel_index(p_ref.x(), p_ref.y(), p_ref.z(), fx, fy, cx, cy, rw, rh);
        if (px == kNoPixel) continue;
        const float z_ref = reference_depth_m_[px];
        if (!(z_ref > 0.0f) || std::abs(z_ref - p_ref.z()) > gate_m) continue;
        const float w = std::abs(r) <= kIntensityHuber ? 1.0f : kIntensityHuber / std::abs(r);
        const Eigen::Vector3f c = (p_w - centre).cross(g);
        const float J[6] = {c.x(), c.y(), c.z(), g.x(), g.y(), g.z()};
        for (int a = 0; a < 6; ++a) {
          const double wa = static_cast<double>(w) * J[a];
          for (int b2 = a; b2 < 6; ++b2) out->H(a, b2) += wa * J[b2];
          out->b(a) += wa * r;
        }
        out->sq_residual += static_cast<double>(r) * r;
        ++out->pairs;
      }
    }
  };
  const int half_rows = (m.height / 2 + step - 1) / step * step;  // a multiple of the step
  PhotometricSums second;
  run_pair(threads_, [&] { pass(0, half_rows, &total); }, [&] { pass(half_rows, m.height, &second); });
  total.merge(second);
  return total;
}

void PhotometricTerm::add_to(const MeasurementImage& m, const Pose& T_world_cam,
                             const Eigen::Vector3f& centre, int level, int step, float gate_m,
                             Eigen::Matrix<double, 6, 6>* H, Eigen::Matrix<double, 6, 1>* b) const {
  if (!ready()) return;
  const PhotometricSums s = sums(m, T_world_cam, centre, level, step, gate_m);
  *H += weight_ * s.H;
  *b += weight_ * s.b;
}

}  // namespace depthfuse
