// Internal: the per-pixel kernels of the photometric term (photometric.hpp): intensity pyramids
// and the residual of one point against a reference image, with its gradient.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "depthfuse/types.hpp"
#include "geometry.hpp"

namespace depthfuse {

// One level of an intensity pyramid: level l has 2^l times fewer pixels a side than the frame.
struct IntensityLevel {
  int width = 0, height = 0;
  std::vector<float> intensity;       // 0..1, row-major
  std::vector<float> grad_u, grad_v;  // d intensity / d pixel of this level (the reference's only)
};

// Luma (ITU-R BT.601) of an RGB image into *levels (resized to `levels` entries): level 0 at the
// image's size, each next one the 2x2 mean of the one before. Reuses the levels' storage.
void build_intensity_pyramid(const ColorImage& color, int levels, std::vector<IntensityLevel>* out);
// Central differences of a level's intensity into its grad_u and grad_v (0 on the border).
void compute_gradients(IntensityLevel* level);

// Bilinear sample of a row-major image at continuous pixel (u, v), which must lie in
// [0, width - 1) x [0, height - 1).
DF_INLINE float bilinear(const float* img, int width, float u, float v) {
  const int u0 = static_cast<int>(u), v0 = static_cast<int>(v);
  const float a = u - static_cast<float>(u0), b = v - static_cast<float>(v0);
  const float* p = img + static_cast<size_t>(v0) * width + u0;
  return (1 - b) * ((1 - a) * p[0] + a * p[1]) + b * ((1 - a) * p[width] + a * p[width + 1]);
}

// The reference a residual is taken against: one pyramid level and the camera, both in the
// reference frame's camera.
struct PhotometricReference {
  const IntensityLevel* level;
  float fx, fy, cx, cy;           // level 0 (the depth camera's) intrinsics
  float level_scale;              // 2^-l: level pixel = (pixel + 0.5) * level_scale - 0.5
  Eigen::Matrix3f R_ref_world;    // world to reference camera
  Eigen::Vector3f t_ref_world;
};

// The photometric residual of a world point p_w whose own intensity is i_frame:
// r = I_ref(pi(T_ref_world * p_w)) - i_frame, and its gradient with respect to p_w (intensity per
// metre). False where the point does not project inside the reference level (with a pixel to
// spare for the bilinear sample). *p_ref: the point in the reference camera.
DF_INLINE bool photometric_residual(const PhotometricReference& ref, const Eigen::Vector3f& p_w,
                                    float i_frame, float* r, Eigen::Vector3f* dr_dp_w,
                                    Eigen::Vector3f* p_ref) {
  const Eigen::Vector3f p = ref.R_ref_world * p_w + ref.t_ref_world;
  *p_ref = p;
  if (!(p.z() > 1e-3f)) return false;
  const float inv_z = 1.0f / p.z();
  const float s = ref.level_scale;
  const float u = (ref.fx * p.x() * inv_z + ref.cx + 0.5f) * s - 0.5f;
  const float v = (ref.fy * p.y() * inv_z + ref.cy + 0.5f) * s - 0.5f;
  const IntensityLevel& L = *ref.level;
  // Gradients are 0 on the border: keep one pixel clear of it.
  if (!(u >= 1.0f && v >= 1.0f && u < static_cast<float>(L.width - 2) &&
        v < static_cast<float>(L.height - 2)))
    return false;
  *r = bilinear(L.intensity.data(), L.width, u, v) - i_frame;
  const float gu = bilinear(L.grad_u.data(), L.width, u, v) * s;  // per pixel of level 0
  const float gv = bilinear(L.grad_v.data(), L.width, u, v) * s;
  // d(u, v)/dp of the pinhole projection, applied to the image gradient: the gradient in the
  // reference camera, then rotated into the world (p = R * p_w + t).
  const Eigen::Vector3f g_ref(gu * ref.fx * inv_z, gv * ref.fy * inv_z,
                              -(gu * ref.fx * p.x() + gv * ref.fy * p.y()) * inv_z * inv_z);
  *dr_dp_w = ref.R_ref_world.transpose() * g_ref;
  return true;
}

}  // namespace depthfuse
