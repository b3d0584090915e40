#include "depthfuse/map_deformation.hpp"
#include "depthfuse/pose_delta.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>
#include <tuple>

#include "chunk_merge.hpp"
#include "deformation_kernels.hpp"
#include "depthfuse/base/log.hpp"
#include "model_projection.hpp"

DF_LOG_CATEGORY(Deformation)

namespace depthfuse {

namespace {

// The chunks a frame sees, sampled as fusion samples them (frame_chunk_keys()'s default), with a
// margin at the faces (update_visible_now()). Not the stretch of the rays in front of the surface:
// fusion only counts violations on points there, it neither merges into them nor adds any.
constexpr int kVisibleStride = 8;
constexpr double kFusionMarginM = 0.1;  // Fuser::fuse()'s select_chunks() margin
// How far registration may move a frame's pose before fusion, at the view's farthest point,
// before the chunks around the view are listed again: ICP moves it by millimetres.
constexpr double kPoseSlackM = 0.05;
// Two keyframes whose motions differ by less than this at a place moved their points there as one:
// far less than a fused point's uncertainty (a millimetre or more), so what fusion left apart there
// stays apart. The merge pass pairs no such points, and skips a chunk whose keyframes all moved so.
// (Without it, a rigid move of a fused wall merged 0.13 % of its points: young neighbours of two
// keyframes, which fusion never compares.)
constexpr double kRigidM = 0.5e-3;

Status check_pose(const Pose& T, const std::string& what) {
  const Eigen::Matrix3d R = T.linear();
  if (!T.matrix().allFinite()) return invalid_argument(what + " is not finite");
  if (orthonormality_error(T) > 1e-6 || R.determinant() <= 0)
    return invalid_argument(what + " is not a rotation and a translation");
  return Status::ok();
}

// The last keyframe whose first frame is at most frame_id (0 before the first), by a binary search
// without branches.
uint32_t segment_of(const std::vector<uint32_t>& first_frame, uint32_t frame_id) {
  const uint32_t* base = first_frame.data();
  size_t n = first_frame.size();
  if (n == 0) return 0;
  while (n > 1) {
    const size_t half = n / 2;
    base = base[half] <= frame_id ? base + half : base;
    n -= half;
  }
  return static_cast<uint32_t>(base - first_frame.data());
}

// segment_of() for a run of points: a chunk's points come from a few segments, in runs, so the
// last segment found is tried first.
class SegmentCursor {
 public:
  explicit SegmentCursor(const std::vector<uint32_t>& first_frame) : first_(first_frame) {}
  uint32_t operator()(uint32_t frame_id) {
    if (frame_id < lo_ || frame_id >= hi_) {
      k_ = segment_of(first_, frame_id);
      lo_ = k_ == 0 ? 0 : first_[k_];
      hi_ = k_ + 1 < first_.size() ? first_[k_ + 1] : ~0u;
    }
    return k_;
  }

 private:
  const std::vector<uint32_t>& first_;
  uint32_t lo_ = 1, hi_ = 0, k_ = 0;
};

}  // namespace

// The keyframes' motions from one version to the current one, worked out as points need them
// (a chunk's points come from a few keyframes of the scan's many); the merge pass, for which it
// says whether the correction moved two keyframes apart at a point.
struct MapDeformation::Scratch : PairGate {
  struct Motion {
    RigidMotionF m;
    bool identity = false;  // the keyframe did not move: its points are left untouched
  };
  std::vector<Motion> motion;  // per keyframe, valid where stamp[k] == current
  std::vector<uint32_t> stamp;
  uint32_t current = 0;
  uint32_t from = ~0u, to = ~0u;                    // the motions' versions
  const std::vector<StoredPose>* before = nullptr;  // the poses at `from` and now
  const std::vector<StoredPose>* now = nullptr;
  // The keyframes the points of the chunk being merged came from, each once (seen[k] == chunk).
  std::vector<uint32_t> present;
  std::vector<uint32_t> seen;
  uint32_t chunk = 0;
  std::vector<uint8_t> keep;
  std::vector<uint32_t> segment;
  ChunkMerger merger;

  const Motion& motion_of(uint32_t k) {
    Motion& m = motion[k];
    if (stamp[k] == current) return m;
    stamp[k] = current;
    // A keyframe that did not exist at that version has no points of it (they were fused later,
    // in a chunk already up to date); one whose pose is the same did not move.
    m.identity =
        k >= before->size() || std::memcmp(&(*before)[k], &(*now)[k], sizeof(StoredPose)) == 0;
    if (!m.identity) {
      const Pose M = load((*now)[k]) * load((*before)[k]).inverse();
      m.m.R = M.linear().cast<float>();
      m.m.t = M.translation().cast<float>();
    }
    return m;
  }
  Eigen::Vector3d apply(uint32_t k, const Eigen::Vector3d& x) {
    const Motion& m = motion_of(k);
    return m.identity ? x : (m.m.R.cast<double>() * x + m.m.t.cast<double>()).eval();
  }
  bool moved_apart(uint32_t a, uint32_t b, const Eigen::Vector3f& p) override {
    const Eigen::Vector3d x = p.cast<double>();
    return (apply(a, x) - apply(b, x)).norm() > kRigidM;
  }
};

MapDeformation::MapDeformation(double point_range_m)
    : point_range_m_(point_range_m),
      poses_(1),
      max_motion_m_(1, 0.0),
      scratch_(std::make_unique<Scratch>()) {}

MapDeformation::~MapDeformation() = default;
MapDeformation::MapDeformation(MapDeformation&&) noexcept = default;
MapDeformation& MapDeformation::operator=(MapDeformation&&) noexcept = default;

MapDeformation::StoredPose MapDeformation::store(const Pose& T) {
  const Eigen::Quaterniond q(T.linear());
  return {{q.w(), q.x(), q.y(), q.z()},
          {T.translation().x(), T.translation().y(), T.translation().z()}};
}

Pose MapDeformation::load(const StoredPose& s) {
  Pose T = Pose::Identity();
  T.linear() = Eigen::Quaterniond(s.q[0], s.q[1], s.q[2], s.q[3]).normalized().toRotationMatrix();
  T.translation() = Eigen::Vector3d(s.t[0], s.t[1], s.t[2]);
  return T;
}

Status MapDeformation::keyframe_added(uint32_t keyframe, uint32_t first_frame_id,
                                      const Pose& T_world_kf) {
  const std::string name = "keyframe " + std::to_string(keyframe);
  if (keyframe != first_frame_.size())
    return invalid_argument(name + " added out of order: the next keyframe is " +
                            std::to_string(first_frame_.size()));
  if (!first_frame_.empty() && first_frame_id <= first_frame_.back())
    return invalid_argument(name + ": its first frame " + std::to_string(first_frame_id) +
                            " is not after keyframe " + std::to_string(keyframe - 1) + "'s (" +
                            std::to_string(first_frame_.back()) + ")");
  DF_RETURN_IF_ERROR(check_pose(T_world_kf, name + "'s pose"));
  first_frame_.push_back(first_frame_id);
  poses_.back().push_back(store(T_world_kf));
  return Status::ok();
}

uint32_t MapDeformation::keyframe_of(uint32_t frame_id) const {
  return segment_of(first_frame_, frame_id);
}

Result<uint32_t> MapDeformation::correct(const std::vector<Pose>& T_world_kf) {
  if (T_world_kf.empty()) return invalid_argument("a correction without poses");
  if (T_world_kf.size() > first_frame_.size())
    return invalid_argument("a correction of " + std::to_string(T_world_kf.size()) +
                            " keyframes, but only " + std::to_string(first_frame_.size()) +
                            " were added");
  if (version_ == std::numeric_limits<uint32_t>::max())
    return invalid_argument("no version left after " + std::to_string(version_));
  for (size_t k = 0; k < T_world_kf.size(); ++k)
    DF_RETURN_IF_ERROR(
        check_pose(T_world_kf[k], "the corrected pose of keyframe " + std::to_string(k)));
  const std::vector<StoredPose>& before = poses_.back();
  std::vector<StoredPose> after(before.size());
  for (size_t k = 0; k < T_world_kf.size(); ++k) after[k] = store(T_world_kf[k]);
  // Keyframes the graph did not have yet ride along with the last one it did.
  const size_t last = T_world_kf.size() - 1;
  const Pose ride = T_world_kf[last] * load(before[last]).inverse();
  for (size_t k = T_world_kf.size(); k < before.size(); ++k)
    after[k] = store(ride * load(before[k]));
  const double bound = max_motion(before, after);
  const size_t riding = before.size() - T_world_kf.size();
  poses_.push_back(std::move(after));  // `before` is gone
  max_motion_m_.push_back(bound);
  ++version_;
  DF_LOG(Deformation, Debug) << "version " << version_ << ": " << T_world_kf.size()
                             << " keyframes corrected, " << riding
                             << " ride along; points move up to " << bound << " m";
  return version_;
}

double MapDeformation::max_motion(const std::vector<StoredPose>& before,
                                  const std::vector<StoredPose>& after) const {
  // A point of keyframe k lies within point_range_m of its camera c: it moves at most as far as c
  // does plus the rotation's chord at that range.
  double bound = 0;
  for (size_t k = 0; k < before.size(); ++k) {
    const Pose T_before = load(before[k]);
    const Pose M = load(after[k]) * T_before.inverse();
    const Eigen::Vector3d c = T_before.translation();
    const double angle = Eigen::AngleAxisd(M.linear()).angle();
    bound = std::max(bound, (M * c - c).norm() + 2.0 * std::sin(0.5 * angle) * point_range_m_);
  }
  return bound;
}

double MapDeformation::reach_m() const {
  double sum = 0;
  for (size_t i = 1; i < max_motion_m_.size(); ++i) sum += max_motion_m_[i];
  return sum;
}

Pose MapDeformation::motion(uint32_t frame_id, uint32_t from_version) const {
  if (from_version >= version_ || from_version < oldest_version_ || first_frame_.empty())
    return Pose::Identity();
  const uint32_t k = keyframe_of(frame_id);
  const std::vector<StoredPose>& before = poses_at(from_version);
  if (k >= before.size()) return Pose::Identity();  // not a keyframe yet at that version
  return load(poses_at(version_)[k]) * load(before[k]).inverse();
}

size_t MapDeformation::move_in_place(PointArrays* points, uint32_t from_version) {
  if (from_version >= version_ || from_version < oldest_version_ || first_frame_.empty())
    return 0;
  prepare_motions(from_version);
  move_points(points, 0, points->size());
  return points->size();
}

void MapDeformation::prepare_motions(uint32_t from) {
  Scratch& s = *scratch_;
  const size_t K = first_frame_.size();
  if (s.from == from && s.to == version_ && s.motion.size() == K) return;
  s.from = from;
  s.to = version_;
  s.before = &poses_at(from);
  s.now = &poses_at(version_);
  s.motion.resize(K);
  s.stamp.resize(K, 0);
  if (++s.current == 0) {  // wrapped: every stamp is stale again
    std::fill(s.stamp.begin(), s.stamp.end(), 0);
    s.current = 1;
  }
}

void MapDeformation::move_points(PointArrays* a, size_t begin, size_t end) {
  Scratch& s = *scratch_;
  SegmentCursor segment(first_frame_);
  for (size_t i = begin; i < end; ++i) {
    const Scratch::Motion& m = s.motion_of(segment(a->state[i].last_frame));
    if (!m.identity) move_point(*a, i, m.m);
  }
}

void MapDeformation::send(PointMap* map, const ChunkKey& key, const PointArrays& from, size_t i,
                          const Chunk& from_chunk) {
  ++stats_.points_crossed;
  Chunk* dest = map->find(key);
  if (!dest && !(stored_elsewhere_ && stored_elsewhere_(key))) {
    dest = &map->get_or_create(key);  // at version_ (update_range() set the map's)
    dest->last_touched_frame = from_chunk.last_touched_frame;
    dest->last_seen_frame = from_chunk.last_seen_frame;
  }
  if (dest && dest->version == version_) {
    if (touched_.empty() || touched_.back().first != key)
      touched_.emplace_back(key, dest->points().size());
    dest->points_for_write().push_back(from.position_m[i], from.state[i]);
    touch(dest);
    return;
  }
  // Not up to date (moving it would move this point a second time), or out of memory.
  ++stats_.points_pending;
  std::vector<PendingGroup>& groups = pending_[key];
  if (groups.empty() || groups.back().version != version_) groups.push_back({version_, {}});
  groups.back().points.push_back(from.position_m[i], from.state[i]);
}

size_t MapDeformation::move_chunk(PointMap* map, const ChunkKey& key, Chunk* chunk) {
  PointArrays& a = chunk->points_for_write();
  const uint32_t from = chunk->version;
  size_t updated = 0;
  // Its own points, then those it was sent while it was not up to date, each from its version.
  const auto move_from = [&](uint32_t from, PointArrays* points) {
    if (from == version_) return;
    if (from < oldest_version_ || from > version_) {
      stats_.points_unmovable += points->size();
      DF_LOG(Deformation, Warning)
          << "chunk (" << key.x << ", " << key.y << ", " << key.z << "): " << points->size()
          << " points at version " << from << ", outside the history kept (" << oldest_version_
          << " to " << version_ << "), stay where they are";
      return;
    }
    prepare_motions(from);
    move_points(points, 0, points->size());
    updated += points->size();
  };
  move_from(chunk->version, &a);
  auto pending = pending_.find(key);
  if (pending != pending_.end()) {
    for (PendingGroup& g : pending->second) {
      move_from(g.version, &g.points);
      a.append(g.points);
    }
    pending_.erase(pending);
  }
  // A merge still queued for it joins this one (merge_updated()): its points move and some leave,
  // so it is merged whole, for the corrections since the older of the two versions.
  uint32_t merge_from = from;
  auto queued = merge_queue_.find(key);
  if (queued != merge_queue_.end()) {
    merge_from = std::min(merge_from, queued->second.from);
    merge_queue_.erase(queued);
  }
  chunk->version = version_;
  touch(chunk);
  // Points now in another chunk go there.
  std::vector<uint8_t>& keep = scratch_->keep;
  keep.assign(a.size(), 1);
  bool left = false;
  for (size_t i = 0; i < a.size(); ++i) {
    const ChunkKey k = map->key_for(a.position_m[i]);
    if (k == key) continue;
    send(map, k, a, i, *chunk);
    keep[i] = 0;
    left = true;
  }
  if (left) a.compact(keep);
  ++stats_.chunks_updated;
  stats_.points_updated += updated;
  updated_.push_back({key, merge_from});
  return updated;
}

bool MapDeformation::moved_rigidly(const PointArrays& a, const Eigen::Vector3f& origin_m,
                                   float size_m) {
  // The keyframes present against the first one, at the chunk's corners: a rigid motion's
  // difference is largest at one of them.
  Scratch& s = *scratch_;
  if (++s.chunk == 0) {  // wrapped
    std::fill(s.seen.begin(), s.seen.end(), 0);
    s.chunk = 1;
  }
  s.seen.resize(first_frame_.size(), 0);
  s.present.clear();
  uint32_t last = ~0u;
  for (size_t i = 0; i < a.size(); ++i) {
    const uint32_t k = s.segment[i];
    if (k != last && s.seen[k] != s.chunk) {
      s.seen[k] = s.chunk;
      s.present.push_back(k);
    }
    last = k;
  }
  for (int c = 0; c < 8; ++c) {
    const Eigen::Vector3f x =
        origin_m + size_m * Eigen::Vector3f(c & 1, (c >> 1) & 1, (c >> 2) & 1);
    for (size_t p = 1; p < s.present.size(); ++p)
      if (s.moved_apart(s.present[0], s.present[p], x)) return false;
  }
  return true;
}

void MapDeformation::merge_updated(PointMap* map, bool defer) {
  const auto by_key = [](const UpdatedChunk& a, const UpdatedChunk& b) {
    return a.key < b.key;
  };
  std::sort(updated_.begin(), updated_.end(), by_key);
  const auto job = [&](const MergeJob& j) {
    // One merge per chunk: a job still queued for it joins this one.
    MergeJob merged = j;
    auto queued = merge_queue_.find(j.key);
    if (queued != merge_queue_.end()) {
      merged.first = std::min(merged.first, queued->second.first);
      merged.from = std::min(merged.from, queued->second.from);
      merge_queue_.erase(queued);
    }
    if (!defer) {
      run_merge(map, merged);
    } else {
      merge_queue_.emplace(merged.key, merged);
      merge_fifo_.push_back(merged.key);
    }
  };
  for (const UpdatedChunk& u : updated_) job({u.key, 0, u.from});
  // Chunks up to date before that took points in: the points taken in against all of theirs, for
  // the last correction.
  std::sort(touched_.begin(), touched_.end());
  for (size_t t = 0; t < touched_.size(); ++t) {
    const ChunkKey& k = touched_[t].first;
    if (t > 0 && touched_[t - 1].first == k) continue;  // the first has the lowest index
    const auto u = std::lower_bound(updated_.begin(), updated_.end(), UpdatedChunk{k, 0}, by_key);
    if (u != updated_.end() && u->key == k) continue;  // merged whole
    job({k, touched_[t].second, std::max(oldest_version_, version_ - 1)});
  }
  updated_.clear();
  touched_.clear();
}

size_t MapDeformation::run_merge(PointMap* map, const MergeJob& job) {
  Chunk* c = map->find(job.key);
  if (!c) return 0;  // evicted since: its surfaces stay as they are
  Scratch& s = *scratch_;
  const PointArrays& a = c->points();
  // A job restored from a checkpoint whose chunk changed since (a later checkpoint's frames
  // replayed into it) may point past its points: nothing of those was taken in.
  if (job.first >= a.size() && job.first > 0) return 0;
  s.segment.resize(a.size());
  SegmentCursor segment(first_frame_);
  for (size_t i = 0; i < a.size(); ++i) s.segment[i] = segment(a.state[i].last_frame);
  // Pairs whose keyframes the corrections since `from` moved apart: none if they all moved the
  // chunk alike (most chunks a closure moves: those one stretch of the walk saw).
  prepare_motions(job.from);
  if (moved_rigidly(a, map->chunk_origin_m(job.key), static_cast<float>(map->chunk_size_m())))
    return a.size();
  PointArrays& merging = c->points_for_write();
  const size_t merged = s.merger.merge(&merging, job.first, &s.segment, &s);
  stats_.points_merged += merged;
  if (merged > 0) touch(c);
  return merging.size() + merged;
}

size_t MapDeformation::run_queued_merges(PointMap* map, size_t max_points) {
  size_t points = 0;
  while (merge_fifo_head_ < merge_fifo_.size() && points < max_points) {
    auto queued = merge_queue_.find(merge_fifo_[merge_fifo_head_++]);
    if (queued == merge_queue_.end()) continue;  // merged since, with its chunk
    const MergeJob job = queued->second;
    merge_queue_.erase(queued);
    points += run_merge(map, job);
  }
  if (merge_fifo_head_ >= merge_fifo_.size()) {
    merge_fifo_.clear();
    merge_fifo_head_ = 0;
  }
  return points;
}

size_t MapDeformation::update_range(PointMap* map, const ChunkKey* keys, size_t count,
                                    size_t max_points, bool defer_merges, size_t* updated) {
  map->set_version(version_);
  size_t i = 0;
  for (; i < count && *updated < max_points; ++i) {
    Chunk* c = map->find(keys[i]);
    if (!c) {
      // Points pending for a chunk that is neither here nor stored elsewhere (it lost its points
      // meanwhile, or a resumed scan's file had none left for it) start it again.
      if (!pending_.count(keys[i]) || (stored_elsewhere_ && stored_elsewhere_(keys[i]))) continue;
      c = &map->get_or_create(keys[i]);  // at version_
    }
    if (c->version == version_ && (pending_.empty() || !pending_.count(keys[i]))) continue;
    *updated += move_chunk(map, keys[i], c);
  }
  merge_updated(map, defer_merges);
  return i;
}

size_t MapDeformation::update(PointMap* map, const std::vector<ChunkKey>& keys) {
  size_t updated = 0;
  update_range(map, keys.data(), keys.size(), std::numeric_limits<size_t>::max(), false, &updated);
  return updated;
}

void MapDeformation::update_visible_now(PointMap* map, const MeasurementImage& m,
                                        const Pose& T_world_cam) {
  // The chunks holding points within this of what the frame sees: a stale point within reach of
  // the view may move into it, fusion looks its margin beyond its samples, and registration may
  // move the pose before fusion (update_visible_if_moved()).
  const double size = map->chunk_size_m();
  const double margin = reach_m() + kFusionMarginM + kPoseSlackM;
  if (margin < size) {
    frame_chunk_keys(*map, m, T_world_cam, static_cast<float>(margin), kVisibleStride, &keys_,
                     &near_, false);
    covered_spare_m_ = kPoseSlackM;
  } else {
    // Farther than the next chunk: every chunk within as many around those it sees.
    frame_chunk_keys(*map, m, T_world_cam, 0.0f, kVisibleStride, &keys_, &near_, false);
    const int r = static_cast<int>(std::ceil(margin / size));
    near_.clear();
    for (const ChunkKey& k : keys_) {
      ChunkKey n;
      for (n.x = k.x - r; n.x <= k.x + r; ++n.x)
        for (n.y = k.y - r; n.y <= k.y + r; ++n.y)
          for (n.z = k.z - r; n.z <= k.z + r; ++n.z) near_.push_back(n);
    }
    std::sort(near_.begin(), near_.end());
    near_.erase(std::unique(near_.begin(), near_.end()), near_.end());
    keys_.swap(near_);
    covered_spare_m_ = r * size - (margin - kPoseSlackM);
  }
  covered_T_world_cam_ = T_world_cam;
  covered_version_ = version_;
  // Moved now, merged by the sweeps of the next frames: the merge pass costs several times what
  // moving does, and the view holds many chunks.
  size_t updated = 0;
  update_range(map, keys_.data(), keys_.size(), std::numeric_limits<size_t>::max(), true, &updated);
}

void MapDeformation::update_visible_if_moved_now(PointMap* map, const MeasurementImage& m,
                                                 const Pose& T_world_cam) {
  // How far a point in view moves with the camera's change of pose, at most.
  const Pose delta = covered_T_world_cam_.inverse() * T_world_cam;
  const double shift =
      delta.translation().norm() +
      2.0 * std::sin(0.5 * Eigen::AngleAxisd(delta.linear()).angle()) * point_range_m_;
  if (covered_version_ == version_ && shift < covered_spare_m_) return;
  update_visible_now(map, m, T_world_cam);
}

size_t MapDeformation::sweep_now(PointMap* map, const Eigen::Vector3d& camera_m,
                                 size_t max_points) {
  if (sweep_version_ != version_) {
    // Listed once per correction, nearest to the camera then first: the camera moves little
    // while the sweep runs.
    sweep_version_ = version_;
    sweep_next_ = 0;
    std::vector<std::pair<float, ChunkKey>> by_distance;
    const Eigen::Vector3f cam = camera_m.cast<float>();
    const float half = 0.5f * static_cast<float>(map->chunk_size_m());
    map->for_each_chunk([&](const ChunkKey& k, const Chunk& c) {
      if (c.version == version_ && !pending_.count(k)) return;
      const Eigen::Vector3f centre = map->chunk_origin_m(k) + Eigen::Vector3f::Constant(half);
      by_distance.emplace_back((centre - cam).squaredNorm(), k);
    });
    std::sort(by_distance.begin(), by_distance.end());
    sweep_keys_.clear();
    for (const auto& e : by_distance) sweep_keys_.push_back(e.second);
    sweep_done_ = false;
  }
  if (sweep_done_) return 0;
  // The merges the view's chunks left (they are where the camera is), then the stale chunks.
  size_t updated = run_queued_merges(map, max_points);
  if (updated < max_points && sweep_next_ < sweep_keys_.size())
    sweep_next_ +=
        update_range(map, sweep_keys_.data() + sweep_next_, sweep_keys_.size() - sweep_next_,
                     max_points - updated, false, &updated);
  if (sweep_next_ >= sweep_keys_.size() && merge_queue_.empty()) {
    sweep_done_ = true;
    drop_unneeded_history(*map);
  }
  return updated;
}

size_t MapDeformation::bring_all_up_to_date(PointMap* map) {
  keys_.clear();
  map->for_each_chunk([&](const ChunkKey& k, const Chunk& c) {
    if (c.version != version_ || (!pending_.empty() && pending_.count(k))) keys_.push_back(k);
  });
  // In key order: the result does not depend on the hash table's.
  std::sort(keys_.begin(), keys_.end());
  size_t updated = 0;
  update_range(map, keys_.data(), keys_.size(), std::numeric_limits<size_t>::max(), false,
               &updated);
  run_queued_merges(map, std::numeric_limits<size_t>::max());
  sweep_version_ = version_;
  sweep_keys_.clear();
  sweep_next_ = 0;
  sweep_done_ = true;
  drop_unneeded_history(*map);
  return updated;
}

uint32_t MapDeformation::oldest_version_needed(const PointMap& map) const {
  uint32_t oldest = version_;
  map.for_each_chunk(
      [&](const ChunkKey&, const Chunk& c) { oldest = std::min(oldest, c.version); });
  for (const auto& kv : pending_)
    for (const PendingGroup& g : kv.second) oldest = std::min(oldest, g.version);
  for (const auto& kv : merge_queue_) oldest = std::min(oldest, kv.second.from);
  if (oldest_stored_) oldest = std::min(oldest, *oldest_stored_);
  return oldest;
}

void MapDeformation::drop_unneeded_history(const PointMap& map) {
  const size_t dropped = forget_versions_before(oldest_version_needed(map));
  if (dropped > 0)
    DF_LOG(Deformation, Debug) << "dropped the poses of " << dropped << " versions; kept "
                               << oldest_version_ << " to " << version_;
}

size_t MapDeformation::forget_versions_before(uint32_t version) {
  version = std::min(version, version_);
  if (version <= oldest_version_) return 0;
  const size_t n = version - oldest_version_;
  poses_.erase(poses_.begin(), poses_.begin() + static_cast<std::ptrdiff_t>(n));
  max_motion_m_.erase(max_motion_m_.begin(),
                      max_motion_m_.begin() + static_cast<std::ptrdiff_t>(n));
  oldest_version_ = version;
  // Scratch motions may refer to a version dropped.
  scratch_->from = scratch_->to = ~0u;
  return n;
}

DeformationHistory MapDeformation::history() const {
  DeformationHistory h;
  h.keyframe_first_frame = first_frame_;
  h.oldest_version = oldest_version_;
  h.max_motion_m = max_motion_m_;
  for (const std::vector<StoredPose>& v : poses_) {
    h.T_world_kf.emplace_back();
    for (const StoredPose& p : v) h.T_world_kf.back().push_back(load(p));
  }
  // In the FIFO's order; a key queued again after a merge joined it appears once, where its job
  // runs (its first entry still queued).
  std::unordered_map<ChunkKey, bool, ChunkKeyHash> listed;
  for (size_t i = merge_fifo_head_; i < merge_fifo_.size(); ++i) {
    const auto queued = merge_queue_.find(merge_fifo_[i]);
    if (queued == merge_queue_.end() || !listed.emplace(queued->first, true).second) continue;
    const MergeJob& j = queued->second;
    h.merges.push_back({j.key, static_cast<uint32_t>(j.first), j.from});
  }
  return h;
}

Status MapDeformation::restore(const DeformationHistory& h) {
  for (size_t k = 1; k < h.keyframe_first_frame.size(); ++k)
    if (h.keyframe_first_frame[k] <= h.keyframe_first_frame[k - 1])
      return invalid_argument("deformation history: keyframe " + std::to_string(k) +
                              "'s first frame is not after keyframe " + std::to_string(k - 1) +
                              "'s");
  if (h.T_world_kf.empty()) return invalid_argument("deformation history: no version");
  if (h.max_motion_m.size() != h.T_world_kf.size())
    return invalid_argument("deformation history: " + std::to_string(h.T_world_kf.size()) +
                            " versions of poses but " + std::to_string(h.max_motion_m.size()) +
                            " motion bounds");
  if (uint64_t{h.oldest_version} + h.T_world_kf.size() - 1 > std::numeric_limits<uint32_t>::max())
    return invalid_argument("deformation history: versions beyond the last");
  if (h.T_world_kf.back().size() != h.keyframe_first_frame.size())
    return invalid_argument("deformation history: the current version has " +
                            std::to_string(h.T_world_kf.back().size()) + " keyframe poses for " +
                            std::to_string(h.keyframe_first_frame.size()) + " keyframes");
  std::vector<std::vector<StoredPose>> poses;
  for (size_t v = 0; v < h.T_world_kf.size(); ++v) {
    const std::string version = std::to_string(h.oldest_version + v);
    if (v > 0 && h.T_world_kf[v].size() < h.T_world_kf[v - 1].size())
      return invalid_argument("deformation history: version " + version +
                              " has fewer keyframes than the one before");
    if (!(h.max_motion_m[v] >= 0) || !std::isfinite(h.max_motion_m[v]))
      return invalid_argument("deformation history: version " + version +
                              "'s motion bound is not a distance");
    poses.emplace_back();
    for (size_t k = 0; k < h.T_world_kf[v].size(); ++k) {
      DF_RETURN_IF_ERROR(check_pose(
          h.T_world_kf[v][k],
          "deformation history: version " + version + "'s pose of keyframe " + std::to_string(k)));
      poses.back().push_back(store(h.T_world_kf[v][k]));
    }
  }
  const uint32_t last_version = static_cast<uint32_t>(h.oldest_version + h.T_world_kf.size() - 1);
  for (const DeformationHistory::QueuedMerge& m : h.merges)
    if (m.from_version < h.oldest_version || m.from_version > last_version)
      return invalid_argument("deformation history: the merge pass queued for chunk (" +
                              std::to_string(m.key.x) + ", " + std::to_string(m.key.y) + ", " +
                              std::to_string(m.key.z) + ") counts from version " +
                              std::to_string(m.from_version) + ", outside the history kept");
  clear();
  for (const DeformationHistory::QueuedMerge& m : h.merges) {
    if (!merge_queue_.emplace(m.key, MergeJob{m.key, m.first_point, m.from_version}).second)
      continue;  // listed twice: the first runs
    merge_fifo_.push_back(m.key);
  }
  first_frame_ = h.keyframe_first_frame;
  oldest_version_ = h.oldest_version;
  version_ = static_cast<uint32_t>(h.oldest_version + h.T_world_kf.size() - 1);
  poses_ = std::move(poses);
  max_motion_m_ = h.max_motion_m;
  sweep_version_ = ~0u;  // the next sweep lists the chunks the history says are stale
  return Status::ok();
}

void MapDeformation::clear() {
  first_frame_.clear();
  version_ = oldest_version_ = 0;
  poses_.assign(1, {});
  max_motion_m_.assign(1, 0.0);
  oldest_stored_.reset();
  pending_.clear();
  scratch_->from = scratch_->to = ~0u;
  covered_version_ = ~0u;
  merge_queue_.clear();
  merge_fifo_.clear();
  merge_fifo_head_ = 0;
  sweep_version_ = 0;
  sweep_keys_.clear();
  sweep_next_ = 0;
  sweep_done_ = true;
  stats_ = {};
}

size_t MapDeformation::pending_points() const {
  size_t n = 0;
  for (const auto& kv : pending_)
    for (const PendingGroup& g : kv.second) n += g.points.size();
  return n;
}

std::vector<ChunkKey> MapDeformation::pending_keys() const {
  std::vector<ChunkKey> keys;
  keys.reserve(pending_.size());
  for (const auto& kv : pending_) keys.push_back(kv.first);
  std::sort(keys.begin(), keys.end());
  return keys;
}

std::vector<PendingPoints> MapDeformation::pending() const {
  std::vector<PendingPoints> out;
  for (const ChunkKey& key : pending_keys())
    for (const PendingGroup& g : pending_.at(key)) out.push_back({key, g.version, g.points});
  return out;
}

Status MapDeformation::restore_pending(std::vector<PendingPoints> pending) {
  std::sort(pending.begin(), pending.end(), [](const PendingPoints& a, const PendingPoints& b) {
    return std::tie(a.key, a.version) < std::tie(b.key, b.version);
  });
  for (size_t i = 0; i < pending.size(); ++i) {
    const PendingPoints& p = pending[i];
    const std::string what = "points pending for chunk (" + std::to_string(p.key.x) + ", " +
                             std::to_string(p.key.y) + ", " + std::to_string(p.key.z) +
                             ") at version " + std::to_string(p.version);
    if (p.version < oldest_version_ || p.version > version_)
      return invalid_argument(what + ": outside the history kept (" +
                              std::to_string(oldest_version_) + " to " + std::to_string(version_) +
                              ")");
    if (i > 0 && pending[i - 1].key == p.key && pending[i - 1].version == p.version)
      return invalid_argument(what + ": given twice");
  }
  pending_.clear();
  for (PendingPoints& p : pending)
    if (!p.points.empty()) pending_[p.key].push_back({p.version, std::move(p.points)});
  return Status::ok();
}

size_t MapDeformation::memory_bytes() const {
  size_t bytes = sizeof(*this) + first_frame_.capacity() * sizeof(uint32_t) +
                 max_motion_m_.capacity() * sizeof(double) +
                 poses_.capacity() * sizeof(std::vector<StoredPose>);
  for (const auto& v : poses_) bytes += v.capacity() * sizeof(StoredPose);
  bytes += pending_.bucket_count() * sizeof(void*);
  for (const auto& kv : pending_) {
    bytes += sizeof(kv) + kv.second.capacity() * sizeof(PendingGroup);
    for (const PendingGroup& g : kv.second) bytes += g.points.memory_bytes();
  }
  const Scratch& s = *scratch_;
  bytes += sizeof(Scratch) + s.motion.capacity() * sizeof(Scratch::Motion) +
           (s.stamp.capacity() + s.present.capacity() + s.seen.capacity()) * sizeof(uint32_t) +
           s.keep.capacity() + s.segment.capacity() * sizeof(uint32_t) + s.merger.memory_bytes();
  bytes += merge_queue_.bucket_count() * sizeof(void*) +
           merge_queue_.size() * (sizeof(MergeJob) + 2 * sizeof(void*));
  bytes += (keys_.capacity() + near_.capacity() + sweep_keys_.capacity() + merge_fifo_.capacity()) *
               sizeof(ChunkKey) +
           updated_.capacity() * sizeof(UpdatedChunk) + touched_.capacity() * sizeof(touched_[0]);
  return bytes;
}

}  // namespace depthfuse
