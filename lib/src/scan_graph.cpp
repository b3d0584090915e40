#include "depthfuse/scan_graph.hpp"

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include "frame_measure.hpp"
#include "thumbnail.hpp"

namespace depthfuse {

static_assert(std::tuple_size<decltype(KeyframeCloud::thumbnail)>::value ==
                  std::tuple_size<Thumbnail>::value,
              "KeyframeCloud keeps thumbnail.hpp's thumbnail");

size_t KeyframeCloud::memory_bytes() const {
  return sizeof(*this) + (position_m.capacity() + normal.capacity()) * sizeof(Eigen::Vector3f);
}

KeyframeCloud make_keyframe_cloud(const MeasurementImage& m, const LoopClosureConfig& c) {
  struct Cell {
    Eigen::Vector3f sum_p = Eigen::Vector3f::Zero(), sum_n = Eigen::Vector3f::Zero();
    int count = 0;
  };
  // Cubes of voxel_m keyed by their integer coordinates, packed (21 bits each: +-1 km at 1 mm).
  const float inv = 1.0f / static_cast<float>(std::max(1e-3, c.voxel_m));
  std::unordered_map<uint64_t, Cell> cells;
  cells.reserve(4096);
  for (int v = 0; v < m.height; v += 2) {
    for (int u = 0; u < m.width; u += 2) {
      const size_t i = static_cast<size_t>(v) * m.width + u;
      if (!m.valid[i] || m.nz[i] == 0.0f) continue;
      const Eigen::Vector3f p(m.x[i], m.y[i], m.z[i]);
      auto q = [&](float x) { return static_cast<uint64_t>(static_cast<int64_t>(std::floor(x * inv)) + (1 << 20)) & 0x1FFFFF; };
      Cell& cell = cells[(q(p.x()) << 42) | (q(p.y()) << 21) | q(p.z())];
      cell.sum_p += p;
      cell.sum_n += Eigen::Vector3f(m.nx[i], m.ny[i], m.nz[i]);
      ++cell.count;
    }
  }
  KeyframeCloud cloud;
  cloud.thumbnail = make_thumbnail(m);
  std::vector<std::pair<uint64_t, const Cell*>> ordered;  // by key: the same cloud every run
  ordered.reserve(cells.size());
  for (const auto& [key, cell] : cells) ordered.emplace_back(key, &cell);
  std::sort(ordered.begin(), ordered.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  const size_t keep = static_cast<size_t>(std::max(1, c.max_points));
  const double stride = std::max(1.0, static_cast<double>(ordered.size()) / keep);
  cloud.position_m.reserve(std::min(keep, ordered.size()));
  cloud.normal.reserve(std::min(keep, ordered.size()));
  for (double k = 0; k < ordered.size(); k += stride) {
    const Cell& cell = *ordered[static_cast<size_t>(k)].second;
    const Eigen::Vector3f n = cell.sum_n / static_cast<float>(cell.count);
    if (n.norm() < 0.5f) continue;  // the cube's normals disagree: a crease or noise
    cloud.position_m.push_back(cell.sum_p / static_cast<float>(cell.count));
    cloud.normal.push_back(n.normalized());
  }
  return cloud;
}

const Pose& AppliedCorrection::motion_of(uint32_t frame_id) const {
  static const Pose kIdentity = Pose::Identity();
  // The last keyframe whose segment starts at or before the frame.
  const auto it = std::upper_bound(first_frame_id.begin(), first_frame_id.end(), frame_id);
  if (it == first_frame_id.begin()) return kIdentity;
  return motion[static_cast<size_t>(it - first_frame_id.begin()) - 1];
}

ScanGraph::ScanGraph(const LoopClosureConfig& config) : config_(config) {}

void ScanGraph::clear() {
  keyframes_.clear();
  odometry_.clear();
  odometry_covariance_.clear();
  loops_.clear();
  since_keyframe_.setZero();
  last_placed_.reset();
  version_ = 0;
  clouds_checked_ = 0;
}

void ScanGraph::frame_tracked(const Pose& T_world_cam, const Matrix6d& covariance) {
  // The uncertainty of this frame's pose relative to the last keyframe: what it was for the last
  // frame, carried along rigidly, and this frame's own (its registration's innovation: small where
  // the depth decided, the motion prior's where it did not).
  if (last_placed_)
    since_keyframe_ = delta_adjoint(last_placed_->inverse() * T_world_cam) * since_keyframe_ *
                          delta_adjoint(last_placed_->inverse() * T_world_cam).transpose() +
                      covariance;
  last_placed_ = T_world_cam;
}

bool ScanGraph::frame_fused(uint32_t frame_id, int64_t utime, const Pose& T_world_cam,
                            const Matrix6d& covariance, const MeasurementImage& m) {
  frame_tracked(T_world_cam, covariance);
  if (!keyframes_.empty()) {
    const Pose& last = keyframes_.back().T_world_kf;
    const bool moved = (T_world_cam.translation() - last.translation()).norm() >= config_.keyframe_spacing_m;
    const bool turned = rotation_between_deg(last, T_world_cam) >= config_.keyframe_spacing_deg;
    if (!moved && !turned) return false;
  }
  GraphKeyframe k;
  k.frame_id = frame_id;
  k.utime = utime;
  k.T_world_kf = T_world_cam;
  k.cloud = std::make_shared<const KeyframeCloud>(make_keyframe_cloud(m, config_));
  if (!keyframes_.empty()) {
    PoseGraphEdge e;
    e.from = static_cast<uint32_t>(keyframes_.size() - 1);
    e.to = static_cast<uint32_t>(keyframes_.size());
    e.T_from_to = keyframes_.back().T_world_kf.inverse() * T_world_cam;
    // A floor of (0.1 mm)^2 and (1e-5 rad)^2 keeps it invertible where the depth said everything.
    Matrix6d cov = 0.5 * (since_keyframe_ + since_keyframe_.transpose());
    cov.diagonal().array() += 1e-10;
    e.information = cov.inverse();
    e.kind = PoseGraphEdge::Kind::kOdometry;
    odometry_.push_back(e);
    odometry_covariance_.push_back(cov);
  }
  keyframes_.push_back(std::move(k));
  since_keyframe_.setZero();
  return true;
}

AppliedCorrection ScanGraph::apply(const GraphCorrection& c) {
  AppliedCorrection applied;
  applied.first_frame_id.reserve(keyframes_.size());
  applied.motion.reserve(keyframes_.size());
  Pose motion = Pose::Identity();
  for (size_t i = 0; i < keyframes_.size(); ++i) {
    // Keyframes made after the graph was given to the loop closer move with the last it optimised.
    if (i < c.T_world_kf.size()) motion = c.T_world_kf[i] * keyframes_[i].T_world_kf.inverse();
    const Pose moved = orthonormalised(motion * keyframes_[i].T_world_kf);
    applied.max_translation_m =
        std::max(applied.max_translation_m,
                 (moved.translation() - keyframes_[i].T_world_kf.translation()).norm());
    keyframes_[i].T_world_kf = moved;
    applied.first_frame_id.push_back(keyframes_[i].frame_id);
    applied.motion.push_back(motion);
  }
  if (last_placed_ && !applied.motion.empty()) last_placed_ = applied.motion.back() * *last_placed_;
  loops_ = c.loops;
  applied.loops = loops_.size();
  applied.version = ++version_;
  return applied;
}

size_t ScanGraph::forget_redundant_clouds(size_t searched) {
  const size_t bound = static_cast<size_t>(config_.max_cloud_mib * 1024.0 * 1024.0);
  size_t bytes = 0;
  for (const GraphKeyframe& k : keyframes_)
    if (k.cloud) bytes += k.cloud->memory_bytes();
  size_t forgotten = 0;
  for (searched = std::min(searched, keyframes_.size()); clouds_checked_ < searched && bytes > bound;
       ++clouds_checked_) {
    GraphKeyframe& k = keyframes_[clouds_checked_];
    if (!k.has_points()) continue;
    for (size_t i = 0; i < clouds_checked_; ++i) {
      const GraphKeyframe& older = keyframes_[i];
      if (!older.has_points() ||
          (older.T_world_kf.translation() - k.T_world_kf.translation()).norm() >= config_.cloud_spacing_m ||
          rotation_between_deg(older.T_world_kf, k.T_world_kf) >= config_.cloud_spacing_deg)
        continue;
      // A new cloud rather than a cleared one: the loop closer's snapshots share the old one.
      auto thumbnail_only = std::make_shared<KeyframeCloud>();
      thumbnail_only->thumbnail = k.cloud->thumbnail;
      bytes = bytes - k.cloud->memory_bytes() + thumbnail_only->memory_bytes();
      k.cloud = std::move(thumbnail_only);
      ++forgotten;
      break;
    }
  }
  return forgotten;
}

ScanGraphState ScanGraph::state() const {
  return ScanGraphState{keyframes_, odometry_, odometry_covariance_, loops_, version_};
}

Status ScanGraph::restore(ScanGraphState s) {
  const size_t n = s.keyframes.size();
  const std::string what = "pose graph";
  if (s.odometry.size() != (n > 0 ? n - 1 : 0) || s.odometry_covariance.size() != s.odometry.size())
    return invalid_argument(what + ": " + std::to_string(n) + " keyframes but " +
                            std::to_string(s.odometry.size()) + " odometry edges");
  for (size_t i = 0; i < n; ++i) {
    if (!s.keyframes[i].cloud)
      return invalid_argument(what + ": keyframe " + std::to_string(i) + " has no cloud");
    if (i > 0 && s.keyframes[i].frame_id <= s.keyframes[i - 1].frame_id)
      return invalid_argument(what + ": keyframe " + std::to_string(i) + "'s frame " +
                              std::to_string(s.keyframes[i].frame_id) +
                              " is not after the previous one's");
  }
  for (size_t i = 0; i < s.odometry.size(); ++i)
    if (s.odometry[i].from != i || s.odometry[i].to != i + 1)
      return invalid_argument(what + ": odometry edge " + std::to_string(i) +
                              " does not join keyframes " + std::to_string(i) + " and " +
                              std::to_string(i + 1));
  for (const PoseGraphEdge& e : s.loops)
    if (e.from >= n || e.to >= n)
      return invalid_argument(what + ": a loop edge joins keyframes " + std::to_string(e.from) +
                              " and " + std::to_string(e.to) + " of " + std::to_string(n));
  keyframes_ = std::move(s.keyframes);
  odometry_ = std::move(s.odometry);
  odometry_covariance_ = std::move(s.odometry_covariance);
  loops_ = std::move(s.loops);
  version_ = s.version;
  clouds_checked_ = 0;
  forget_redundant_clouds(keyframes_.size());
  since_keyframe_.setZero();
  last_placed_.reset();
  if (!keyframes_.empty()) last_placed_ = keyframes_.back().T_world_kf;
  return Status::ok();
}

size_t ScanGraph::memory_bytes() const {
  size_t bytes = sizeof(*this) + keyframes_.capacity() * sizeof(GraphKeyframe) +
                 (odometry_.capacity() + loops_.capacity()) * sizeof(PoseGraphEdge) +
                 odometry_covariance_.capacity() * sizeof(Matrix6d);
  for (const auto& k : keyframes_)
    if (k.cloud) bytes += k.cloud->memory_bytes();
  return bytes;
}

}  // namespace depthfuse
