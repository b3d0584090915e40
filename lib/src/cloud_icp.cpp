#include "cloud_icp.hpp"

#include <algorithm>
#include <cmath>
#include <unordered_map>
#include <vector>

#include <Eigen/Eigenvalues>

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

// H less its noise N, in H's eigen-directions: each eigenvalue less N's share along it, at least 0.
Matrix6d without_noise(const Matrix6d& H, const Matrix6d& N) {
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(0.5 * (H + H.transpose()));
  if (eig.info() != Eigen::Success) return H;
  Vector6d kept;
  for (int d = 0; d < 6; ++d) {
    const auto u = eig.eigenvectors().col(d);
    kept(d) = std::max(0.0, eig.eigenvalues()(d) - u.dot(N * u));
  }
  return eig.eigenvectors() * kept.asDiagonal() * eig.eigenvectors().transpose();
}

}  // namespace

CloudAlignment align_clouds(const KeyframeCloud& source, const KeyframeCloud& target,
                            const Pose& T_target_source_initial, const LoopClosureConfig& config) {
  CloudAlignment out;
  out.T_target_source = T_target_source_initial;
  if (source.size() < 50 || target.size() < 50) return out;
  Pose T = T_target_source_initial;
  Matrix6d H = Matrix6d::Zero();
  // For the share of H that the normals' noise makes (see below): the sum of what a tilt of
  // variance 1 rad^2 would add to the pairs' J J^T, and the pairs' squared normal differences.
  Matrix6d H_unit_tilt = Matrix6d::Zero();
  double sq_tilt = 0;
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
      H_unit_tilt.setZero();
      sq_tilt = 0;
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
        // A tilt e of the normal (e across n_s) adds [p x e; e] to J: in H, w times its
        // covariance, which is (tilt^2 / 2) (I - n n^T) for a tilt equally likely in any direction.
        // Only the last pass's is used, and that is always on the finest level.
        if (level == 0) {
          const Eigen::Matrix3d P =
              Eigen::Matrix3d::Identity() - n_s.cast<double>() * n_s.cast<double>().transpose();
          const Eigen::Matrix3d X = skew(p.cast<double>());
          H_unit_tilt.topLeftCorner<3, 3>() += w * X * P * X.transpose();
          H_unit_tilt.topRightCorner<3, 3>() += w * X * P;
          H_unit_tilt.bottomLeftCorner<3, 3>() += w * P * X.transpose();
          H_unit_tilt.bottomRightCorner<3, 3>() += w * P;
          sq_tilt += (R * source.normal[i] - n_t).squaredNorm();
        }
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
  // The normals are the cubes' and carry noise; H, built from them, then has curvature where the
  // cost has none: along a bare wall, a tilt of the normals pairs the motion along the wall with a
  // residual. A loop edge would then hold whatever the initial pose said along the wall (the
  // odometry's drift) as if it had measured it. The tilt's variance is measured from the pairs
  // (two normals of one surface differ by two tilts), and its share of H taken out, direction by
  // direction, none left below zero.
  const double tilt2 = sq_tilt / (2.0 * pairs);
  const double pair_variance = noise2 + config.model_error_m * config.model_error_m * weight_sum;
  out.information = without_noise(H, 0.5 * tilt2 * H_unit_tilt) / pair_variance;
  out.followed_information = H / pair_variance;
  return out;
}

}  // namespace depthfuse
