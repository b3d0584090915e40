#include "loop_closure.hpp"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>

#include <Eigen/Eigenvalues>

#include "cloud_icp.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/pose_delta.hpp"
#include "frame_measure.hpp"
#include "relocaliser.hpp"
#include "thumbnail.hpp"

DF_LOG_CATEGORY(LoopClosure)

namespace depthfuse {

namespace {

// A correction smaller than this moves the map by less than its noise: its loops are kept for the
// next optimisation, and the map is not touched.
constexpr double kMinCorrectionM = 0.002;
constexpr double kMinCorrectionDeg = 0.1;

// The covariance of a loop edge from its information, a direction without any capped at 1 m / 1 rad.
Matrix6d capped_covariance(const Matrix6d& information) {
  const Eigen::SelfAdjointEigenSolver<Matrix6d> es(0.5 * (information + information.transpose()));
  Vector6d inv = es.eigenvalues();
  for (int k = 0; k < 6; ++k) inv(k) = 1.0 / std::max(inv(k), 1.0);
  return es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose();
}

// Whether the graph already relates the loop's two keyframes as its edge does, to within what a
// correction must move to be applied: then an optimisation would leave the map where it is, and
// only costs the loop closer's time, which grows with the graph.
bool agrees_with_graph(const GraphSnapshot& s, const PoseGraphEdge& e) {
  const Pose T_from_to = s.keyframes[e.from].T_world_kf.inverse() * s.keyframes[e.to].T_world_kf;
  return (T_from_to.inverse() * e.T_from_to).translation().norm() < kMinCorrectionM &&
         rotation_between_deg(T_from_to, e.T_from_to) < kMinCorrectionDeg;
}

double angle_deg(const Pose& a, const Pose& b) {
  // Between the optical axes.
  const double c = a.linear().col(2).dot(b.linear().col(2));
  return std::acos(std::clamp(c, -1.0, 1.0)) * 180.0 / M_PI;
}

}  // namespace

LoopCloser::LoopCloser(const LoopClosureConfig& config, const RelocalisationConfig& place_search,
                       bool background)
    : config_(config), place_search_(place_search), background_(background) {
  if (background_) thread_ = std::thread([this] { run(); });
}

LoopCloser::~LoopCloser() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void LoopCloser::submit(GraphSnapshot snapshot) {
  if (!background_) {
    const size_t first = searched_;
    searched_ = snapshot.keyframes.size();
    std::optional<GraphCorrection> c = process(snapshot, first);
    std::lock_guard<std::mutex> lock(mutex_);
    if (c) correction_ = std::move(c);
    done_ = searched_;
    return;
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    pending_ = std::move(snapshot);  // a newer graph supersedes one not started
  }
  wake_.notify_all();
}

void LoopCloser::restore(std::vector<PoseGraphEdge> loops, size_t searched) {
  std::lock_guard<std::mutex> lock(mutex_);
  loops_ = std::move(loops);
  searched_ = searched;
  done_ = searched;
  stats_.loops = loops_.size();
}

std::optional<GraphCorrection> LoopCloser::take() {
  std::lock_guard<std::mutex> lock(mutex_);
  std::optional<GraphCorrection> c = std::move(correction_);
  correction_.reset();
  return c;
}

void LoopCloser::wait_idle() {
  std::unique_lock<std::mutex> lock(mutex_);
  idle_.wait(lock, [this] { return !busy_ && !pending_; });
}

LoopClosureStats LoopCloser::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

size_t LoopCloser::searched() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return done_;
}

void LoopCloser::run() {
  // Loop closure has seconds of slack, fusion none: on two cores it takes their idle time.
  setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), 10);
  for (;;) {
    GraphSnapshot s;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait(lock, [this] { return stop_ || pending_; });
      if (stop_) return;
      s = std::move(*pending_);
      pending_.reset();
      busy_ = true;
    }
    const size_t first = std::min(searched_, s.keyframes.size());
    searched_ = s.keyframes.size();
    std::optional<GraphCorrection> c = process(s, first);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (c) correction_ = std::move(c);
      done_ = searched_;
      busy_ = false;
    }
    idle_.notify_all();
  }
}

std::optional<GraphCorrection> LoopCloser::process(const GraphSnapshot& s, size_t first) {
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<PoseGraphEdge> found;
  for (size_t k = first; k < s.keyframes.size(); ++k) search(s, k, &found);
  std::optional<GraphCorrection> correction;
  const bool agreed = std::all_of(found.begin(), found.end(), [&](const PoseGraphEdge& e) {
    return agrees_with_graph(s, e);
  });
  if (!found.empty() && agreed) {
    // Kept without a solve: the next optimisation has them, and may still refuse them then.
    std::lock_guard<std::mutex> lock(mutex_);
    loops_.insert(loops_.end(), found.begin(), found.end());
    stats_.loops = loops_.size();
    ++stats_.loops_agreed;
  } else if (!found.empty()) {
    std::vector<PoseGraphEdge> loops = loops_;
    loops.insert(loops.end(), found.begin(), found.end());
    std::vector<Pose> poses;
    poses.reserve(s.keyframes.size());
    for (const auto& k : s.keyframes) poses.push_back(k.T_world_kf);
    std::vector<PoseGraphEdge> edges = s.odometry;
    edges.insert(edges.end(), loops.begin(), loops.end());
    PoseGraphOptions options;
    options.loop_loss_scale = config_.loop_loss_scale;
    options.loop_chi2_reject = config_.loop_chi2_reject;
    const size_t window = static_cast<size_t>(std::max(0, config_.optimise_window_keyframes));
    if (window > 0 && poses.size() > window)
      options.first_free_node = static_cast<uint32_t>(poses.size() - window);
    Result<PoseGraphResult> r = optimise_pose_graph(poses, edges, options);
    std::lock_guard<std::mutex> lock(mutex_);
    ++stats_.optimisations;
    if (!r) {
      DF_LOG(LoopClosure, Warning) << "pose graph not optimised: " << r.status().to_string();
    } else {
      loops_.clear();
      for (size_t e = 0; e < loops.size(); ++e) {
        if (r->edge_used[s.odometry.size() + e])
          loops_.push_back(loops[e]);
        else
          ++stats_.rejected;
      }
      stats_.loops = loops_.size();
      double moved_m = 0, turned_deg = 0;
      size_t most_moved = 0;
      for (size_t i = 0; i < poses.size(); ++i) {
        const double d = (r->T_world_node[i].translation() - poses[i].translation()).norm();
        if (d > moved_m) {
          moved_m = d;
          most_moved = i;
        }
        turned_deg = std::max(turned_deg, rotation_between_deg(r->T_world_node[i], poses[i]));
      }
      if (moved_m >= kMinCorrectionM || turned_deg >= kMinCorrectionDeg) {
        correction = GraphCorrection{std::move(r->T_world_node), loops_};
        DF_LOG(LoopClosure, Info) << "loop closed at keyframe " << s.keyframes.size() - 1 << ": "
                                  << loops_.size() << " loops, keyframes moved up to "
                                  << moved_m * 1e3 << " mm (keyframe " << most_moved << "), "
                                  << turned_deg << " deg";
      }
    }
  }
  std::lock_guard<std::mutex> lock(mutex_);
  stats_.keyframes_searched += s.keyframes.size() - first;
  stats_.seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return correction;
}

void LoopCloser::search(const GraphSnapshot& s, size_t k, std::vector<PoseGraphEdge>* found) {
  const GraphKeyframe& K = s.keyframes[k];
  if (!K.has_points() || k == 0) return;
  // Walking back along the odometry: the covariance of keyframe k relative to each older one (in
  // k's frame), and the camera path between them.
  struct Candidate {
    double distance_m;
    size_t i;
  };
  std::vector<Candidate> near;
  std::vector<Matrix6d> path_covariance(k);
  std::vector<bool> eligible(k, false);
  Matrix6d covariance = Matrix6d::Zero();
  Matrix6d to_k = Matrix6d::Identity();  // a perturbation of keyframe j + 1 carried to keyframe k
  double path_m = 0;
  for (size_t j = k; j-- > 0;) {
    if (j >= s.odometry.size()) return;  // the graph is not whole: nothing to search
    covariance += to_k * s.odometry_covariance[j] * to_k.transpose();
    to_k = to_k * delta_adjoint(s.odometry[j].T_from_to);
    path_m += s.odometry[j].T_from_to.translation().norm();
    path_covariance[j] = covariance;
    if (k - j < static_cast<size_t>(std::max(1, config_.min_keyframes_back)) || path_m < config_.min_path_m)
      continue;
    const GraphKeyframe& J = s.keyframes[j];
    if (!J.has_points()) continue;
    eligible[j] = true;
    const double d = (J.T_world_kf.translation() - K.T_world_kf.translation()).norm();
    const double sigma_m = std::sqrt(std::max(0.0, covariance.bottomRightCorner<3, 3>().trace()));
    const double radius = std::max(config_.search_radius_m, 3.0 * sigma_m);
    if (d <= radius && angle_deg(J.T_world_kf, K.T_world_kf) <= config_.max_view_angle_deg)
      near.push_back({d, j});
  }
  std::sort(near.begin(), near.end(),
            [](const Candidate& a, const Candidate& b) { return a.distance_m < b.distance_m; });
  near.resize(std::min(near.size(), static_cast<size_t>(std::max(0, config_.candidates_per_keyframe))));
  std::vector<size_t> tried;
  for (const Candidate& c : near) {
    tried.push_back(c.i);
    (void)believe(s, c.i, k, s.keyframes[c.i].T_world_kf.inverse() * K.T_world_kf,
                  path_covariance[c.i], found);
  }
  // The place search: the older keyframe whose thumbnail is most alike, aligned by features.
  const int every = config_.place_search_every_n_keyframes;
  if (every <= 0 || k % static_cast<size_t>(every) != 0) return;
  double best = 0.5;  // below this the thumbnails are not alike
  std::optional<size_t> best_i;
  for (size_t i = 0; i < k; ++i) {
    if (!eligible[i] ||
        std::find(tried.begin(), tried.end(), i) != tried.end())
      continue;
    const double sim = similarity(K.cloud->thumbnail, s.keyframes[i].cloud->thumbnail);
    if (sim > best) {
      best = sim;
      best_i = i;
    }
  }
  if (!best_i) return;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ++stats_.place_searches;
  }
  const std::optional<Pose> T_i_k =
      align_by_features(*K.cloud, *s.keyframes[*best_i].cloud, place_search_,
                        static_cast<unsigned>(k) + 1u);
  if (T_i_k) (void)believe(s, *best_i, k, *T_i_k, path_covariance[*best_i], found);
}

bool LoopCloser::believe(const GraphSnapshot& s, size_t i, size_t k, const Pose& T_i_k_initial,
                         const Matrix6d& path_covariance, std::vector<PoseGraphEdge>* found) {
  const GraphKeyframe& I = s.keyframes[i];
  const GraphKeyframe& K = s.keyframes[k];
  const CloudAlignment a = align_clouds(*K.cloud, *I.cloud, T_i_k_initial, config_);
  std::lock_guard<std::mutex> lock(mutex_);
  ++stats_.candidates;
  if (!a.converged || a.overlap < config_.min_overlap || a.rmse_m > config_.max_rmse_m) {
    DF_LOG(LoopClosure, Debug) << "keyframe " << k << " to " << i << ": not aligned ("
                               << (a.converged ? "" : "no convergence, ") << "overlap "
                               << a.overlap << ", rmse " << a.rmse_m * 1e3 << " mm)";
    return false;
  }
  ++stats_.aligned;
  // The correction the loop asks of the graph, against what the odometry between the two allows
  // (inflated: the odometry's covariance is the tracking's estimate of itself) and the loop's own.
  // The loop's is the curvature the ICP followed, the normals' noise in it: how far an ICP moves
  // along a direction that only the noise curves is the noise's doing, and a loop whose ICP went
  // far that way (a look-alike place) is refused.
  const Vector6d e = pose_delta(I.T_world_kf.inverse() * K.T_world_kf, a.T_target_source);
  const double g = config_.gate_inflation;
  const Matrix6d S = g * g * path_covariance + capped_covariance(a.followed_information);
  const double chi2 = e.dot(S.ldlt().solve(e));
  if (!(chi2 <= config_.gate_chi2)) {
    ++stats_.gated;
    DF_LOG(LoopClosure, Debug) << "keyframe " << k << " to " << i << ": aligned (overlap "
                               << a.overlap << ", rmse " << a.rmse_m * 1e3
                               << " mm) but beyond the odometry's uncertainty (chi2 " << chi2 << ")";
    return false;
  }
  DF_LOG(LoopClosure, Debug) << "keyframe " << k << " to " << i << ": a loop (overlap "
                             << a.overlap << ", rmse " << a.rmse_m * 1e3 << " mm, chi2 " << chi2
                             << ")";
  PoseGraphEdge edge;
  edge.from = static_cast<uint32_t>(i);
  edge.to = static_cast<uint32_t>(k);
  edge.T_from_to = a.T_target_source;
  edge.information = 0.5 * (a.information + a.information.transpose());
  edge.kind = PoseGraphEdge::Kind::kLoop;
  found->push_back(edge);
  return true;
}

}  // namespace depthfuse
