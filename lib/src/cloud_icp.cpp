#include "cloud_icp.hpp"

#include <cmath>
#include <unordered_map>
#include <vector>

namespace depthfuse {

namespace {

// The target's points by cube of `cell_m`.
class CubeGrid {
 public:
  CubeGrid(const KeyframeCloud& cloud, float cell_m) : cloud_(cloud), inv_(1.0f / cell_m) {
    cells_.reserve(cloud.size());
    for (size_t i = 0; i < cloud.size(); ++i) cells_[key(cell_of(cloud.position_m[i]))].push_back(i);
  }
  // The nearest point within `gate_m` of p, or -1.
  long nearest(const Eigen::Vector3f& p, float gate_m) const {
    const Eigen::Vector3i c = cell_of(p);
    long best = -1;
    float best_d2 = gate_m * gate_m;
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          const auto it = cells_.find(key(c + Eigen::Vector3i(dx, dy, dz)));
          if (it == cells_.end()) continue;
          for (const size_t i : it->second) {
            const float d2 = (cloud_.position_m[i] - p).squaredNorm();
            if (d2 < best_d2) {
              best_d2 = d2;
              best = static_cast<long>(i);
            }
          }
        }
    return best;
  }

 private:
  Eigen::Vector3i cell_of(const Eigen::Vector3f& p) const {
    return (p * inv_).array().floor().cast<int>();
  }
  static uint64_t key(const Eigen::Vector3i& c) {
    auto b = [](int v) { return static_cast<uint64_t>(v + (1 << 20)) & 0x1FFFFF; };
    return (b(c.x()) << 42) | (b(c.y()) << 21) | b(c.z());
  }
  const KeyframeCloud& cloud_;
  float inv_;
  std::unordered_map<uint64_t, std::vector<size_t>> cells_;
};

constexpr double kCosMaxNormalAngle = 0.8191520;  // 35 degrees

}  // namespace

CloudAlignment align_clouds(const KeyframeCloud& source, const KeyframeCloud& target,
                            const Pose& T_target_source_initial, const LoopClosureConfig& config) {
  CloudAlignment out;
  out.T_target_source = T_target_source_initial;
  if (source.size() < 50 || target.size() < 50) return out;
  Pose T = T_target_source_initial;
  Matrix6d H = Matrix6d::Zero();
  double sq_residual = 0, weight_sum = 0;
  size_t pairs = 0;
  for (int level = 2; level >= 0; --level) {
    const float gate = static_cast<float>(config.max_correspondence_m * (1 << level));
    const CubeGrid grid(target, gate);
    for (int it = 0; it < 8; ++it) {
      H.setZero();
      Vector6d b = Vector6d::Zero();
      sq_residual = 0;
      weight_sum = 0;
      pairs = 0;
      const Eigen::Matrix3f R = T.linear().cast<float>();
      const Eigen::Vector3f t = T.translation().cast<float>();
      for (size_t i = 0; i < source.size(); ++i) {
        const Eigen::Vector3f p = source.position_m[i];
        const Eigen::Vector3f q = R * p + t;
        const long j = grid.nearest(q, gate);
        if (j < 0) continue;
        const Eigen::Vector3f& n_t = target.normal[static_cast<size_t>(j)];
        if (n_t.dot(R * source.normal[i]) < kCosMaxNormalAngle) continue;
        const float r = n_t.dot(q - target.position_m[static_cast<size_t>(j)]);
        // The Jacobian of r for a right perturbation [w; v] of T (in the source's frame).
        const Eigen::Vector3f n_s = R.transpose() * n_t;
        Vector6d J;
        J << p.cross(n_s).cast<double>(), n_s.cast<double>();
        const double w = std::abs(r) <= 0.5f * gate ? 1.0 : 0.5 * gate / std::abs(r);
        H += w * J * J.transpose();
        b += w * J * r;
        sq_residual += static_cast<double>(r) * r;
        weight_sum += w;
        ++pairs;
      }
      if (pairs < 30) return out;
      const Vector6d delta = H.ldlt().solve(-b);
      if (!delta.allFinite()) return out;
      T = apply_delta(T, delta);
      if (delta.head<3>().norm() < 1e-5 && delta.tail<3>().norm() < 1e-5) break;
    }
  }
  out.converged = true;
  out.T_target_source = T;
  out.pairs = pairs;
  out.overlap = static_cast<double>(pairs) / source.size();
  out.rmse_m = std::sqrt(sq_residual / pairs);
  const double noise2 = std::max(sq_residual / pairs, 2.5e-7);
  out.information = H / (noise2 + config.model_error_m * config.model_error_m * weight_sum);
  return out;
}

}  // namespace depthfuse
