#include "depthfuse/registration.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>

#include "model_projection.hpp"
#include "parallel.hpp"
#include "photometric.hpp"

namespace depthfuse {

Registrar::Registrar(const RegistrationConfig& config)
    : config_(config),
      projection_(std::make_unique<ModelProjection>()),
      photometric_(std::make_unique<PhotometricTerm>(config)) {}

Registrar::~Registrar() = default;

namespace {

// SE(3) exponential of a small twist (rotation part first), applied on the left in the world frame.
inline Pose twist_to_pose(const Eigen::Matrix<double, 6, 1>& xi) {
  Pose T = Pose::Identity();
  const Eigen::Vector3d w = xi.head<3>();
  const double angle = w.norm();
  if (angle > 1e-12) T.linear() = Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
  T.translation() = xi.tail<3>();
  return T;
}

// The Huber loss of a residual r with scale delta (the loss ICP's weights minimise).
inline float huber_cost(float r, float delta) {
  const float a = std::abs(r);
  return a <= delta ? 0.5f * a * a : delta * (a - 0.5f * delta);
}

// One point-to-plane term: residual n.(p - q) with Jacobian [ (p - c) x n, n ] for a twist about
// the centre c, the camera's position (conditioning: rotations about the camera, not the world
// origin).
struct NormalEquations {
  Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
  Eigen::Matrix<double, 6, 1> b = Eigen::Matrix<double, 6, 1>::Zero();
  double sq_residual = 0;
  double cost = 0;         // sum of the pairs' Huber costs
  double sq_lever_m2 = 0;  // sum of |p - c|^2: the rotations' lever arm
  double weight_sum = 0;   // sum of the pairs' Huber weights
  size_t inliers = 0;

  inline void add(const Eigen::Vector3f& p_rel, const Eigen::Vector3f& n, float r, float w,
                  float rho) {
    sq_lever_m2 += static_cast<double>(p_rel.squaredNorm());
    const Eigen::Vector3f c = p_rel.cross(n);
    const float J[6] = {c.x(), c.y(), c.z(), n.x(), n.y(), n.z()};
    for (int a = 0; a < 6; ++a) {
      const double wa = static_cast<double>(w) * J[a];
      for (int b2 = a; b2 < 6; ++b2) H(a, b2) += wa * J[b2];
      b(a) += wa * r;
    }
    sq_residual += static_cast<double>(r) * r;
    cost += rho;
    weight_sum += w;
    ++inliers;
  }

  void merge(const NormalEquations& o) {
    H += o.H;
    b += o.b;
    sq_residual += o.sq_residual;
    cost += o.cost;
    sq_lever_m2 += o.sq_lever_m2;
    weight_sum += o.weight_sum;
    inliers += o.inliers;
  }
};

// The pose change that turns `T` into `A` as a twist about the centre c (the inverse of the update
// T' = Tc * twist_to_pose(xi) * Tc^-1 * T of moved_by_twist()).
inline Eigen::Matrix<double, 6, 1> twist_between(const Pose& T, const Pose& A, const Eigen::Vector3d& c) {
  Pose Tc = Pose::Identity();
  Tc.translation() = c;
  const Pose M = Tc.inverse() * A * T.inverse() * Tc;
  const Eigen::AngleAxisd aa(M.linear());
  Eigen::Matrix<double, 6, 1> xi;
  xi.head<3>() = aa.angle() * aa.axis();
  xi.tail<3>() = M.translation();
  return xi;
}

// The normal equations with the rotations scaled by the pairs' RMS lever arm, so that both halves
// are in metres of point motion, in their eigenbasis.
struct ScaledEquations {
  Eigen::Matrix<double, 6, 1> scale;  // twist = scale .* (twist in metres)
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eigen;
  Eigen::Matrix<double, 6, 1> bs;
  // The smallest eigenvalue over the largest.
  double conditioning() const {
    const auto& lambda = eigen.eigenvalues();  // ascending
    return lambda(5) > 0 ? std::max(0.0, lambda(0)) / lambda(5) : 0.0;
  }
};

inline ScaledEquations scaled(const NormalEquations& eq) {
  ScaledEquations s;
  const Eigen::Matrix<double, 6, 6> H = eq.H.selfadjointView<Eigen::Upper>();
  const double lever_m = std::sqrt(eq.sq_lever_m2 / std::max<size_t>(1, eq.inliers));
  const double inv_lever = lever_m > 1e-6 ? 1.0 / lever_m : 1.0;
  s.scale << inv_lever, inv_lever, inv_lever, 1.0, 1.0, 1.0;
  s.eigen.compute(s.scale.asDiagonal() * H * s.scale.asDiagonal());
  s.bs = s.scale.asDiagonal() * eq.b;
  return s;
}

// The Gauss-Newton step of the normal equations, in the directions the pairs constrain. A view of
// one wall constrains three of the six directions, a wall and a floor five: in a direction with
// (almost) no information the solution follows the noise and the pose slides. The step is solved in
// the scaled eigenbasis, and directions whose eigenvalue is below `degenerate_ratio` times the
// largest take the value of `to_anchor`, the step to the pose they are held at (0: the current
// value; degenerate_ratio 0: solve in all six).
inline Eigen::Matrix<double, 6, 1> solve_step(const ScaledEquations& eq, double degenerate_ratio,
                                              const Eigen::Matrix<double, 6, 1>& to_anchor) {
  const Eigen::Matrix<double, 6, 1>& lambda = eq.eigen.eigenvalues();  // ascending
  const double floor = std::max(degenerate_ratio * lambda(5), 1e-12 * lambda(5) + 1e-30);
  const Eigen::Matrix<double, 6, 1> coeff_data = eq.eigen.eigenvectors().transpose() * (-eq.bs);
  const Eigen::Matrix<double, 6, 1> coeff_anchor =
      eq.eigen.eigenvectors().transpose() * eq.scale.cwiseInverse().asDiagonal() * to_anchor;
  Eigen::Matrix<double, 6, 1> coeff;
  for (int k = 0; k < 6; ++k) coeff(k) = lambda(k) > floor ? coeff_data(k) / lambda(k) : coeff_anchor(k);
  return eq.scale.asDiagonal() * (eq.eigen.eigenvectors() * coeff);
}

// The step in world axes about the camera centre (solve_step's twist) is the camera frame's delta
// (pose_delta.hpp) turned by the camera's rotation, exactly: xi = B * delta, B = diag(R, R).
inline Matrix6d delta_to_twist(const Pose& T) {
  Matrix6d B = Matrix6d::Zero();
  B.topLeftCorner<3, 3>() = T.linear();
  B.bottomRightCorner<3, 3>() = T.linear();
  return B;
}

// The normal equations as an information matrix of the pose: the unweighted point-to-plane sums
// divided by the variance of what a pair measures. That is the residual's noise, and the map's own
// error along the surface normal, which does not average out over the pairs: a direction that only
// slightly tilted normals constrain is measured no better than that error over their tilt.
inline double data_scale(const NormalEquations& eq, double model_error_m) {
  const double noise2 = std::max(eq.sq_residual / std::max<size_t>(1, eq.inliers), 2.5e-7);
  return 1.0 / (noise2 + model_error_m * model_error_m * eq.weight_sum);
}

// The MAP step: the depth's normal equations (scaled to information) with the motion prior's.
// The prior is centred on its prediction, `to_prior` away from the current pose (world twist).
inline Eigen::Matrix<double, 6, 1> solve_map_step(const Eigen::Matrix<double, 6, 6>& H_data,
                                                  const Eigen::Matrix<double, 6, 1>& b_data,
                                                  const Eigen::Matrix<double, 6, 6>& prior_twist,
                                                  const Eigen::Matrix<double, 6, 1>& to_prior) {
  const Eigen::Matrix<double, 6, 6> H = H_data + prior_twist;
  return H.ldlt().solve(-b_data + prior_twist * to_prior);
}

// What the depth's information and the prior's make of the estimate: the covariance, and the
// depth's smallest share over all directions (the generalised eigenvalues mu of the information
// against the prior's, in whatever units: a share mu / (1 + mu)).
void posterior(RegistrationResult* r, const Matrix6d& prior_information) {
  const Matrix6d I = 0.5 * (r->information + r->information.transpose());
  r->covariance = (I + prior_information).inverse();
  const Eigen::GeneralizedSelfAdjointEigenSolver<Matrix6d> ges(I, prior_information);
  const double mu = std::max(0.0, ges.eigenvalues()(0));
  r->data_share = mu / (1.0 + mu);
}

// The covariance of the information alone, a direction without any capped at 1 m or 1 rad.
Matrix6d capped_inverse(const Matrix6d& information) {
  const Eigen::SelfAdjointEigenSolver<Matrix6d> es(0.5 * (information + information.transpose()));
  Eigen::Matrix<double, 6, 1> inv = es.eigenvalues();
  for (int k = 0; k < 6; ++k) inv(k) = 1.0 / std::max(inv(k), 1.0);
  return es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose();
}

}  // namespace

namespace {

// The camera of the registration model: `factor` times coarser than the depth camera. Faster (the
// per-pixel sums stay in cache) but less accurate where a view holds several surfaces (see
// registration.model_downsample in config/depthfuse.toml).
CameraIntrinsics model_intrinsics(const CameraIntrinsics& K, int factor) {
  if (factor <= 1) return K;
  CameraIntrinsics M = K;
  const double f = factor;
  M.width = std::max(1, K.width / factor);
  M.height = std::max(1, K.height / factor);
  M.fx = K.fx / f;
  M.fy = K.fy / f;
  // Pixel centres: continuous coordinate u maps to (u + 0.5) / f - 0.5.
  M.cx = (K.cx + 0.5) / f - 0.5;
  M.cy = (K.cy + 0.5) / f - 0.5;
  return M;
}

}  // namespace

void Registrar::render_model(const MeasurementImage& m, const PointMap& map, const Pose& T_world_cam,
                             double band_m, double max_corr_m, int downsample) {
  ModelProjection& proj = *projection_;
  proj.set_threads(config_.threads);
  proj.select_chunks(map, m, T_world_cam, static_cast<float>(max_corr_m) + 0.05f);
  proj.render_surface(T_world_cam, model_intrinsics(m.intrinsics, downsample),
                      static_cast<float>(band_m), &view_);
  if (proj.rendered_points() == 0) view_.clear();
}

// An ICP step this small (0.1 mrad and 0.1 mm) is done: the pairs change a little at each
// iteration, so on real depth the step rarely gets much smaller, and the iterations left would
// each cost as much as the first for motion far below the sensor's noise.
constexpr double kConvergedStep = 1e-4;

namespace {

// What makes a frame pixel and a model pixel a pair: the model camera that finds the model pixel,
// the normals' largest angle, the pair's largest distance (m), and the Huber scale (m) that weighs
// its residual; every step_px-th row and column is sampled.
struct PairGates {
  int width = 0, height = 0;  // the model camera's
  float fx = 0, fy = 0, cx = 0, cy = 0;
  float cos_max = 0;
  float max_d_m = 0;
  float huber_m = 0;
  int step_px = 1;
};

// The frame's pose in float as the pair search applies it: into the world (T_world_cam, whose
// position is also the centre the twists turn about) and into the camera the model was rendered
// from (T_cam0_cam), where pairs are associated.
struct PairPose {
  Eigen::Matrix3f R_world_cam;
  Eigen::Vector3f t_world_cam;
  Eigen::Matrix3f R_cam0_cam;
  Eigen::Vector3f t_cam0_cam;
};

inline PairPose pair_pose(const Pose& T_world_cam, const Pose& T_cam0_world) {
  PairPose P;
  P.R_world_cam = T_world_cam.linear().cast<float>();
  P.t_world_cam = T_world_cam.translation().cast<float>();
  const Pose T_cam0_cam = T_cam0_world * T_world_cam;
  P.R_cam0_cam = T_cam0_cam.linear().cast<float>();
  P.t_cam0_cam = T_cam0_cam.translation().cast<float>();
  return P;
}

// One iteration's point-to-plane pairs, with the samples taken and those that found a model pixel.
struct PairSums {
  NormalEquations eq;
  size_t sampled = 0;
  size_t modelled = 0;

  void merge(const PairSums& o) {
    eq.merge(o.eq);
    sampled += o.sampled;
    modelled += o.modelled;
  }
};

// The pairs of the frame's rows [v_begin, v_end) against the model's surface.
void add_pairs_in_rows(const MeasurementImage& m, const SurfaceView::Pixel* surface,
                       const PairGates& g, const PairPose& P, int v_begin, int v_end,
                       PairSums* out) {
  const Eigen::Vector3f& centre = P.t_world_cam;
  for (int v = v_begin; v < v_end; v += g.step_px) {
    for (int u = 0; u < m.width; u += g.step_px) {
      const size_t i = static_cast<size_t>(v) * m.width + u;
      if (!m.valid[i] || m.nz[i] == 0.0f) continue;
      ++out->sampled;
      const Eigen::Vector3f p_c(m.x[i], m.y[i], m.z[i]);
      const Eigen::Vector3f p0 = P.R_cam0_cam * p_c + P.t_cam0_cam;
      const uint32_t px =
          pixel_index(p0.x(), p0.y(), p0.z(), g.fx, g.fy, g.cx, g.cy, g.width, g.height);
      if (px == kNoPixel) continue;
      const SurfaceView::Pixel& s = surface[px];
      if (!(s.w > 0.0f)) continue;
      ++out->modelled;
      const Eigen::Vector3f q(s.x, s.y, s.z);
      const Eigen::Vector3f n_q(s.nx, s.ny, s.nz);
      const Eigen::Vector3f p_w = P.R_world_cam * p_c + P.t_world_cam;
      const Eigen::Vector3f d = p_w - q;
      if (d.squaredNorm() > g.max_d_m * g.max_d_m) continue;
      const Eigen::Vector3f n_p = P.R_world_cam * Eigen::Vector3f(m.nx[i], m.ny[i], m.nz[i]);
      if (n_p.dot(n_q) < g.cos_max) continue;
      const float r = n_q.dot(d);
      const float w = std::abs(r) <= g.huber_m ? 1.0f : g.huber_m / std::abs(r);
      out->eq.add(p_w - centre, n_q, r, w, huber_cost(r, g.huber_m));
    }
  }
}

// The pairs from two halves of the rows, on two threads if there are two, summed in the same order
// either way.
PairSums pair_sums(const MeasurementImage& m, const SurfaceView& model, const PairGates& g,
                   const PairPose& P, int threads) {
  const int half_rows = (m.height / 2 + g.step_px - 1) / g.step_px * g.step_px;  // a step multiple
  const SurfaceView::Pixel* surface = model.pixels.data();
  PairSums first, second;
  run_pair(
      threads, [&] { add_pairs_in_rows(m, surface, g, P, 0, half_rows, &first); },
      [&] { add_pairs_in_rows(m, surface, g, P, half_rows, m.height, &second); });
  first.merge(second);
  return first;
}

// The twist (world axes, about `centre`) of one Gauss-Newton step: with a motion prior the MAP
// step, else the step in the directions the pairs constrain, the others held at `anchor` (nullptr:
// where they are).
Eigen::Matrix<double, 6, 1> icp_step(const NormalEquations& eq, const ScaledEquations& scaled_eq,
                                     const Pose& T_world_cam, const Eigen::Vector3f& centre,
                                     const MotionPrior* prior, const Pose* anchor,
                                     double degenerate_ratio, double model_error_m) {
  if (prior) {
    const Matrix6d B = delta_to_twist(T_world_cam);
    const double alpha = data_scale(eq, model_error_m);
    const Matrix6d H = eq.H.selfadjointView<Eigen::Upper>();
    return solve_map_step(alpha * H, alpha * eq.b, B * prior->information * B.transpose(),
                          B * pose_delta(T_world_cam, prior->T_world_cam));
  }
  const Eigen::Matrix<double, 6, 1> to_anchor =
      anchor ? twist_between(T_world_cam, *anchor, centre.cast<double>())
             : Eigen::Matrix<double, 6, 1>::Zero();
  return solve_step(scaled_eq, degenerate_ratio, to_anchor);
}

// The pose moved by a twist about `centre`: T' = Tc * exp(xi) * Tc^-1 * T, its rotation
// re-normalised.
Pose moved_by_twist(const Pose& T_world_cam, const Eigen::Matrix<double, 6, 1>& xi,
                    const Eigen::Vector3f& centre) {
  Pose Tc = Pose::Identity();
  Tc.translation() = centre.cast<double>();
  Pose T = Tc * twist_to_pose(xi) * Tc.inverse() * T_world_cam;
  T.linear() = Eigen::Quaterniond(T.linear()).normalized().toRotationMatrix();
  return T;
}

// How well the last iteration's pairs fit: fitness over the samples and over those with a model
// pixel, the mean Huber cost, the RMS residual.
void set_fit(const PairSums& sums, const PairGates& g, RegistrationResult* result) {
  const NormalEquations& eq = sums.eq;
  result->correspondences = eq.inliers;
  result->fitness = sums.sampled ? static_cast<double>(eq.inliers) / sums.sampled : 0.0;
  result->model_fitness = sums.modelled ? static_cast<double>(eq.inliers) / sums.modelled : 0.0;
  // A sample without a pair costs what a pair at the gate would.
  const double unpaired =
      huber_cost(g.max_d_m, g.huber_m) * static_cast<double>(sums.sampled - eq.inliers);
  result->mean_cost = sums.sampled ? (eq.cost + unpaired) / sums.sampled : 0.0;
  result->rmse_m = eq.inliers ? std::sqrt(eq.sq_residual / eq.inliers) : 0.0;
}

// The estimate's information (of the camera frame's delta) when it converged at T_world_cam, and
// its covariance: with the motion prior's, else alone.
void set_uncertainty(const NormalEquations& eq, const Pose& T_world_cam, double model_error_m,
                     const MotionPrior* prior, RegistrationResult* result) {
  if (result->converged) {
    const Matrix6d B = delta_to_twist(T_world_cam);
    const Matrix6d H = eq.H.selfadjointView<Eigen::Upper>();
    result->information = data_scale(eq, model_error_m) * (B.transpose() * H * B);
  }
  result->motion_prior = prior != nullptr;
  if (prior) {
    posterior(result, prior->information);
    result->prior_innovation = pose_delta(prior->T_world_cam, T_world_cam);
    result->prior_chi2 = result->prior_innovation.dot(prior->information * result->prior_innovation);
  } else {
    result->covariance = capped_inverse(result->information);
  }
}

}  // namespace

RegistrationResult Registrar::run(const MeasurementImage& m, const SurfaceView& model,
                                  const Pose& initial, const Hold& hold, int subsample,
                                  int iterations, double max_corr_m, size_t min_pairs,
                                  int photometric_level) {
  RegistrationResult result;
  result.T_world_cam = initial;
  const CameraIntrinsics& MK = model.K;
  if (model.empty() || model.pixels.size() != static_cast<size_t>(MK.width) * MK.height)
    return result;

  PairGates gates;
  gates.width = MK.width;
  gates.height = MK.height;
  gates.fx = static_cast<float>(MK.fx);
  gates.fy = static_cast<float>(MK.fy);
  gates.cx = static_cast<float>(MK.cx);
  gates.cy = static_cast<float>(MK.cy);
  gates.cos_max = static_cast<float>(std::cos(config_.max_normal_angle_deg * M_PI / 180.0));
  gates.max_d_m = static_cast<float>(max_corr_m);
  gates.huber_m = static_cast<float>(config_.huber_delta_m);
  gates.step_px = std::max(1, subsample);
  min_pairs = std::max<size_t>(6, min_pairs);

  // Associations are made in the camera the model was rendered from.
  const Pose T_cam0_world = model.T_world_cam.inverse();
  Pose T = initial;
  PairSums sums;
  for (int it = 0; it < iterations; ++it) {
    const PairPose P = pair_pose(T, T_cam0_world);
    const Eigen::Vector3f& centre = P.t_world_cam;
    sums = pair_sums(m, model, gates, P, config_.threads);
    result.iterations = it + 1;
    if (sums.eq.inliers < min_pairs) break;
    if (photometric_level >= 0)
      photometric_->add_to(m, T, centre, photometric_level, gates.step_px, gates.max_d_m,
                           &sums.eq.H, &sums.eq.b);
    const ScaledEquations scaled_eq = scaled(sums.eq);
    result.conditioning = scaled_eq.conditioning();
    const Eigen::Matrix<double, 6, 1> xi =
        icp_step(sums.eq, scaled_eq, T, centre, hold.prior, hold.anchor, hold.degenerate_ratio,
                 config_.model_error_m);
    if (!xi.allFinite()) break;
    T = moved_by_twist(T, xi, centre);
    if (xi.head<3>().norm() < kConvergedStep && xi.tail<3>().norm() < kConvergedStep) break;
  }

  set_fit(sums, gates, &result);
  result.converged = sums.eq.inliers >= min_pairs;
  if (result.converged) result.T_world_cam = T;
  set_uncertainty(sums.eq, T, config_.model_error_m, hold.prior, &result);
  return result;
}

// min_correspondences holds at subsample_px. A tracking level samples 4^level times fewer pixels, so
// it needs as many times fewer pairs for the same overlap: otherwise the coarse levels, the only
// ones whose gates reach a large motion, rarely run on a VGA frame with holes (TUM fr1/xyz: the
// coarsest level ran on 7 of 39 frames, and a 9-degree turn was lost).
size_t Registrar::min_pairs(int level) const {
  return static_cast<size_t>(std::max(0, config_.min_correspondences)) >> (2 * level);
}

RegistrationResult Registrar::refine(const MeasurementImage& m, const PointMap& map,
                                     const Pose& T_world_cam_initial) {
  render_model(m, map, T_world_cam_initial, config_.model_band_m, config_.max_correspondence_m,
               config_.model_downsample);
  return refine(m, view_, T_world_cam_initial);
}

RegistrationResult Registrar::refine(const MeasurementImage& m, const SurfaceView& model,
                                     const Pose& T_world_cam_initial) {
  return run(m, model, T_world_cam_initial, hold_for(std::nullopt), config_.subsample_px,
             config_.iterations, config_.max_correspondence_m, min_pairs(0));
}

int Registrar::tracking_levels() const { return std::max(1, config_.tracking_levels); }
int Registrar::tracking_levels_without_motion() const {
  return std::max(1, config_.tracking_levels_without_motion);
}

void Registrar::render_for_tracking(const MeasurementImage& m, const PointMap& map,
                                    const Pose& T_world_cam_initial, int levels) {
  // One rendering of the model, at the initial pose and wide enough for the coarsest gate, serves
  // every level: associations go through the rendered camera whatever the current estimate.
  render_model(m, map, T_world_cam_initial, config_.tracking_model_band_m,
               config_.max_correspondence_m * (1 << (levels - 1)), config_.tracking_model_downsample);
}

RegistrationResult Registrar::track(const MeasurementImage& m, const PointMap& map,
                                    const Pose& T_world_cam_initial, const MotionPrior& prior) {
  render_for_tracking(m, map, T_world_cam_initial, tracking_levels());
  return track(m, view_, T_world_cam_initial, prior);
}

RegistrationResult Registrar::track(const MeasurementImage& m, const SurfaceView& model,
                                    const Pose& T_world_cam_initial, const MotionPrior& prior) {
  return coarse_to_fine(m, model, T_world_cam_initial, Hold{nullptr, 0.0, &prior},
                        tracking_levels());
}

Registrar::Hold Registrar::hold_for(const std::optional<Pose>& T_world_cam_held) const {
  if (T_world_cam_held) return {&*T_world_cam_held, config_.tracking_degenerate_ratio};
  return {nullptr, config_.degenerate_ratio};
}

RegistrationResult Registrar::track(const MeasurementImage& m, const PointMap& map,
                                    const Pose& T_world_cam_initial,
                                    const std::optional<Pose>& T_world_cam_held) {
  render_for_tracking(m, map, T_world_cam_initial, tracking_levels());
  return track(m, view_, T_world_cam_initial, T_world_cam_held);
}

RegistrationResult Registrar::track(const MeasurementImage& m, const SurfaceView& model,
                                    const Pose& T_world_cam_initial,
                                    const std::optional<Pose>& T_world_cam_held) {
  return coarse_to_fine(m, model, T_world_cam_initial, hold_for(T_world_cam_held),
                        tracking_levels());
}

RegistrationResult Registrar::track_without_motion(const MeasurementImage& m, const PointMap& map,
                                                   const Pose& T_world_cam_last) {
  render_for_tracking(m, map, T_world_cam_last, tracking_levels_without_motion());
  return track_without_motion(m, view_, T_world_cam_last);
}

// The motion model's prediction is what keeps a step's start within the coarsest gate of the
// steady levels. Without one the start is the last pose, and a camera that moved fast through a
// gap (a scan's first frame takes longest) starts further away than those gates reach: the
// coarsest level then pairs the wrong surfaces and the track takes a step the wrong way.
RegistrationResult Registrar::track_without_motion(const MeasurementImage& m,
                                                   const SurfaceView& model,
                                                   const Pose& T_world_cam_last) {
  return coarse_to_fine(m, model, T_world_cam_last, hold_for(T_world_cam_last),
                        tracking_levels_without_motion());
}

RegistrationResult Registrar::coarse_to_fine(const MeasurementImage& m, const SurfaceView& model,
                                             const Pose& T_world_cam_initial, const Hold& hold,
                                             int levels) {
  RegistrationResult r;
  r.T_world_cam = T_world_cam_initial;
  Pose T = T_world_cam_initial;
  for (int level = levels - 1; level >= 0; --level) {
    const int step = std::max(1, config_.subsample_px) << level;
    const double gate = config_.max_correspondence_m * (1 << level);
    r = run(m, model, T, hold, step, config_.tracking_iterations_per_level, gate, min_pairs(level),
            level);
    if (r.converged) T = r.T_world_cam;
  }
  r.T_world_cam = T;
  return r;
}

void Registrar::set_frame_color(const ColorImage& color, const MeasurementImage& m) {
  photometric_->set_frame(color, m);
}

void Registrar::keep_frame_as_photometric_reference(const MeasurementImage& m,
                                                    const Pose& T_world_cam) {
  photometric_->keep_frame_as_reference(m, T_world_cam);
}

void Registrar::forget_photometric_reference() { photometric_->clear(); }

const char* to_string(TrackingState s) {
  switch (s) {
    case TrackingState::kTracked: return "tracked";
    case TrackingState::kUncertain: return "uncertain";
    case TrackingState::kLost: return "lost";
  }
  return "?";
}

TrackingState classify_tracking(const RegistrationResult& r, const RegistrationConfig& c,
                                double model_fitness_reference) {
  if (!r.converged || r.fitness < c.tracking_lost_fitness || r.rmse_m > c.tracking_lost_rmse_m)
    return TrackingState::kLost;
  // A poor fitness is a view into unmapped space only if the frame agrees with the map where the
  // map has a surface; where it does not, the camera is somewhere else (a loop wrapping back).
  // "Agrees" is relative to what this sensor's tracked frames score: on real data noisy normals
  // and occluding edges leave ~15 % of a correctly placed frame's samples on the model unpaired.
  if (r.fitness < c.tracking_retry_fitness &&
      r.model_fitness < c.tracking_lost_model_fitness * model_fitness_reference)
    return TrackingState::kLost;
  const bool held = r.motion_prior ? r.data_share < c.tracking_min_data_share
                                   : r.conditioning < c.tracking_degenerate_ratio;
  if (r.fitness < c.tracking_retry_fitness || held) return TrackingState::kUncertain;
  return TrackingState::kTracked;
}

bool relocalisation_verified(const RegistrationResult& r, const RegistrationConfig& c,
                             double model_fitness_reference) {
  return classify_tracking(r, c, model_fitness_reference) == TrackingState::kTracked &&
         r.model_fitness >= c.tracking_lost_model_fitness * model_fitness_reference;
}

}  // namespace depthfuse
