#include "fusion_kernels.hpp"

#include <cmath>
#include <limits>

namespace depthfuse {

DF_VECTOR_CLONES void prepare_row(Vec3Columns<const float> p_cam, Vec3Columns<const float> n_cam,
                                  const CameraInWorld& camera, const SensorModel& model,
                                  const CandidateColumns& c, int width, const RowColumns& row) {
  // The views and the camera copied into locals: the loop's byte stores (merges) may alias what a
  // reference points to, which would reload every pointer each pixel. `ivdep` tells the compiler
  // what it cannot prove (GCC ignores restrict on locals): no store here reaches another
  // iteration's inputs, so it may vectorise.
  const CandidateColumns cand = c;
  const RowColumns out = row;
  const Eigen::Matrix3f R = camera.R;
  const Eigen::Vector3f t = camera.t, up = camera.up;
  DF_IVDEP
  for (int u = 0; u < width; ++u) {
    const Eigen::Vector3f p_c = p_cam[u];
    const Eigen::Vector3f ray_w = rotate(R, p_c);
    const Eigen::Vector3f p_w = ray_w + t;
    const Eigen::Vector3f n_w = rotate(R, n_cam[u]);
    const float range = std::sqrt(p_c.squaredNorm());  // norm() would not vectorise
    float w_x, w_y, w_z;
    model.information_weights(p_c.z(), &w_x, &w_y, &w_z);
    const Sym3f L_n = ray_information(ray_w * (1.0f / range), up, w_x, w_y, w_z);
    Eigen::Vector3f p_f;
    Sym3f L_f;
    out.merges[u] = merge_rule(cand.point.position[u], cand.point.information[u], p_w, L_n, &p_f,
                               &L_f);
    out.measurement.set(u, p_w, L_n, n_w);
    out.range_m[u] = range;
    out.merged_position.set(u, p_f);
    out.merged_normal.set(
        u, running_mean_normal(static_cast<float>(cand.merges[u]), cand.point.normal[u], n_w));
  }
}

DF_VECTOR_CLONES void select_window_3x3(const CandidateColumns& c, size_t first_px, int width,
                                        const RowColumns& row) {
  // One vectorised pass, the eight neighbours written out. It calls nothing: with a call out of its
  // AVX2 clone GCC left out the vzeroupper, and the scalar code after it ran slower.
  const int W = width;
  const PointColumns<float> measurement = row.measurement;
  int32_t* window_px = row.window_px;
  const CandidateColumns above = c.from(first_px - W), same = c.from(first_px),
                         below = c.from(first_px + W);
  const Vec3Columns<const float> a = above.point.position, s = same.point.position,
                                 b = below.point.position;
  const int32_t *as = above.slot, *ss = same.slot, *bs = below.slot;
  const int32_t pa = static_cast<int32_t>(first_px - W), ps = static_cast<int32_t>(first_px),
                pb = static_cast<int32_t>(first_px + W);
  DF_IVDEP
  for (int u = 1; u < W - 1; ++u) {
    const Eigen::Vector3f p_w = measurement.position[u];
    const Sym3f L_n = measurement.information[u];
    float d2 = std::numeric_limits<float>::infinity();
    int32_t px = -1;
    consider_candidate(as[u - 1] >= 0, pa + u - 1, a[u - 1], p_w, L_n, &d2, &px);
    consider_candidate(as[u] >= 0, pa + u, a[u], p_w, L_n, &d2, &px);
    consider_candidate(as[u + 1] >= 0, pa + u + 1, a[u + 1], p_w, L_n, &d2, &px);
    consider_candidate(ss[u - 1] >= 0, ps + u - 1, s[u - 1], p_w, L_n, &d2, &px);
    consider_candidate(ss[u + 1] >= 0, ps + u + 1, s[u + 1], p_w, L_n, &d2, &px);
    consider_candidate(bs[u - 1] >= 0, pb + u - 1, b[u - 1], p_w, L_n, &d2, &px);
    consider_candidate(bs[u] >= 0, pb + u, b[u], p_w, L_n, &d2, &px);
    consider_candidate(bs[u + 1] >= 0, pb + u + 1, b[u + 1], p_w, L_n, &d2, &px);
    window_px[u] = px;
  }
}

}  // namespace depthfuse
