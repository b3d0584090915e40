#include "relocaliser.hpp"

#include <pcl/features/fpfh.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/sample_consensus_prerejective.h>
#include <pcl/search/kdtree.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <numeric>
#include <optional>

#include "depthfuse/base/log.hpp"
#include "depthfuse/scan_graph.hpp"
#include "thumbnail.hpp"

DF_LOG_CATEGORY(Relocalisation)

namespace depthfuse {

namespace {

using Cloud = pcl::PointCloud<pcl::PointNormal>;
using Features = pcl::PointCloud<pcl::FPFHSignature33>;

// The frame's valid measurements with normals (every 2nd pixel in u and v), averaged in cubes of
// voxel_m, then thinned evenly to max_points.
Cloud::Ptr downsample(const MeasurementImage& m, const RelocalisationConfig& c) {
  Cloud::Ptr dense(new Cloud);
  dense->reserve(m.pixel_count() / 4);
  for (int v = 0; v < m.height; v += 2) {
    for (int u = 0; u < m.width; u += 2) {
      const size_t i = static_cast<size_t>(v) * m.width + u;
      if (!m.valid[i] || m.nz[i] == 0.0f) continue;
      pcl::PointNormal p;
      p.x = m.x[i];
      p.y = m.y[i];
      p.z = m.z[i];
      p.normal_x = m.nx[i];
      p.normal_y = m.ny[i];
      p.normal_z = m.nz[i];
      p.curvature = 0.0f;
      dense->push_back(p);
    }
  }
  Cloud::Ptr sparse(new Cloud);
  if (dense->empty()) return sparse;
  pcl::VoxelGrid<pcl::PointNormal> grid;
  const float leaf = static_cast<float>(c.voxel_m);
  grid.setLeafSize(leaf, leaf, leaf);
  grid.setInputCloud(dense);
  grid.filter(*sparse);
  const size_t keep = static_cast<size_t>(std::max(1, c.max_points));
  Cloud::Ptr out(new Cloud);
  out->reserve(std::min(keep, sparse->size()));
  const double stride = std::max(1.0, static_cast<double>(sparse->size()) / keep);
  for (double k = 0; k < sparse->size(); k += stride) {
    pcl::PointNormal p = (*sparse)[static_cast<size_t>(k)];
    const Eigen::Vector3f n = p.getNormalVector3fMap();
    if (n.norm() < 0.5f) continue;  // the voxel's normals disagree: a crease or noise
    p.getNormalVector3fMap() = n.normalized();
    out->push_back(p);
  }
  return out;
}

// FPFH features of `cloud`; points whose neighbourhood is too sparse for a feature are dropped
// from both (the feature search needs finite values).
Features::Ptr describe(Cloud::Ptr* cloud, double radius_m) {
  Features::Ptr features(new Features);
  if ((*cloud)->empty()) return features;
  pcl::FPFHEstimation<pcl::PointNormal, pcl::PointNormal, pcl::FPFHSignature33> fpfh;
  fpfh.setInputCloud(*cloud);
  fpfh.setInputNormals(*cloud);
  fpfh.setSearchMethod(pcl::search::KdTree<pcl::PointNormal>::Ptr(new pcl::search::KdTree<pcl::PointNormal>));
  fpfh.setRadiusSearch(radius_m);
  fpfh.compute(*features);
  Cloud::Ptr kept(new Cloud);
  Features::Ptr kept_features(new Features);
  for (size_t i = 0; i < features->size(); ++i) {
    const float* h = (*features)[i].histogram;
    if (!std::all_of(h, h + 33, [](float x) { return std::isfinite(x); })) continue;
    kept->push_back((**cloud)[i]);
    kept_features->push_back((*features)[i]);
  }
  *cloud = kept;
  return kept_features;
}

double rotation_deg(const Pose& a, const Pose& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle() * 180.0 / M_PI;
}

// A keyframe already stands for a frame this near it (the keyframe spacing).
bool within_spacing(const RelocalisationConfig& c, const Pose& a, const Pose& b) {
  return (a.translation() - b.translation()).norm() < c.keyframe_spacing_m &&
         rotation_deg(a, b) < c.keyframe_spacing_deg;
}

// Fewer points than this carry no shape worth matching (a wall, or nothing).
constexpr size_t kMinPoints = 50;

// PCL's prerejective sample consensus of source to target by their features: the pose of source in
// target's frame, or nothing.
std::optional<Pose> sample_consensus(const Cloud::Ptr& source, const Features::Ptr& source_features,
                                     const Cloud::Ptr& target, const Features::Ptr& target_features,
                                     const RelocalisationConfig& config, unsigned seed) {
  pcl::SampleConsensusPrerejective<pcl::PointNormal, pcl::PointNormal, pcl::FPFHSignature33> sac;
  sac.setInputSource(source);
  sac.setSourceFeatures(source_features);
  sac.setInputTarget(target);
  sac.setTargetFeatures(target_features);
  sac.setMaximumIterations(config.sac_iterations);
  sac.setNumberOfSamples(3);
  sac.setCorrespondenceRandomness(2);  // one of the 2 nearest features, not always the nearest
  sac.setSimilarityThreshold(0.9f);    // the sample's edge lengths must agree to 10 %
  sac.setMaxCorrespondenceDistance(config.sac_inlier_m);
  sac.setInlierFraction(static_cast<float>(config.sac_inlier_fraction));
  // PCL draws its samples with rand(): seeded here so that a run can be repeated.
  std::srand(seed);
  Cloud aligned;
  sac.align(aligned);
  if (!sac.hasConverged()) return std::nullopt;
  Pose T_target_source = Pose::Identity();
  T_target_source.matrix() = sac.getFinalTransformation().cast<double>();
  return T_target_source;
}

// A keyframe's points as PCL's cloud.
Cloud::Ptr to_cloud(const KeyframeCloud& k) {
  Cloud::Ptr cloud(new Cloud);
  cloud->reserve(k.size());
  for (size_t i = 0; i < k.size(); ++i) {
    pcl::PointNormal p;
    p.getVector3fMap() = k.position_m[i];
    p.getNormalVector3fMap() = k.normal[i];
    p.curvature = 0.0f;
    cloud->push_back(p);
  }
  return cloud;
}

}  // namespace

std::optional<Pose> align_by_features(const KeyframeCloud& source, const KeyframeCloud& target,
                                      const RelocalisationConfig& config, unsigned seed) {
  Cloud::Ptr s = to_cloud(source), t = to_cloud(target);
  const Features::Ptr fs = describe(&s, config.feature_radius_m);
  const Features::Ptr ft = describe(&t, config.feature_radius_m);
  if (s->size() < kMinPoints || t->size() < kMinPoints) return std::nullopt;
  return sample_consensus(s, fs, t, ft, config, seed);
}

struct Relocaliser::Keyframe {
  Pose T_world_cam;
  uint32_t frame_id = 0;
  Thumbnail thumbnail;
  Cloud::Ptr cloud;           // camera frame
  Features::Ptr features;     // computed when first searched
};

Relocaliser::Relocaliser(const RelocalisationConfig& config) : config_(config) {}

Relocaliser::~Relocaliser() = default;

void Relocaliser::clear() {
  keyframes_.clear();
  lost_frames_ = 0;
}

size_t Relocaliser::memory_bound_bytes(const RelocalisationConfig& c, size_t pixels) {
  if (!c.enabled) return 0;
  const size_t per_point = sizeof(pcl::PointNormal) + sizeof(pcl::FPFHSignature33);
  const size_t keyframe = sizeof(Keyframe) + static_cast<size_t>(std::max(0, c.max_points)) * per_point;
  // downsample(): every 4th pixel as a point, and the voxel grid's index of each.
  const size_t search = pixels / 4 * (sizeof(pcl::PointNormal) + 2 * sizeof(size_t));
  return static_cast<size_t>(std::max(0, c.max_keyframes) + 1) * keyframe + search;
}

bool Relocaliser::wants(const Pose& T_world_cam) const {
  if (!config_.enabled || keyframes_.size() >= static_cast<size_t>(std::max(0, config_.max_keyframes)))
    return false;
  for (const auto& k : keyframes_)
    if (within_spacing(config_, k->T_world_cam, T_world_cam)) return false;
  return true;
}

// A keyframe of the frame, or nothing when its points carry too little shape.
std::unique_ptr<Relocaliser::Keyframe> Relocaliser::make_keyframe(const MeasurementImage& m,
                                                                  const Pose& T_world_cam,
                                                                  uint32_t frame_id) const {
  auto k = std::make_unique<Keyframe>();
  k->T_world_cam = T_world_cam;
  k->frame_id = frame_id;
  k->thumbnail = make_thumbnail(m);
  k->cloud = downsample(m, config_);
  if (k->cloud->size() < kMinPoints) return nullptr;
  return k;
}

bool Relocaliser::add_older_keyframe(const MeasurementImage& m, const Pose& T_world_cam,
                                     uint32_t frame_id) {
  if (!wants(T_world_cam)) return false;
  std::unique_ptr<Keyframe> k = make_keyframe(m, T_world_cam, frame_id);
  if (!k) return false;
  keyframes_.insert(keyframes_.begin(), std::move(k));
  return true;
}

void Relocaliser::move_keyframes(const std::function<Pose(uint32_t, const Pose&)>& moved) {
  for (auto& k : keyframes_) k->T_world_cam = moved(k->frame_id, k->T_world_cam);
}

void Relocaliser::frame_tracked(const MeasurementImage& m, const Pose& T_world_cam,
                                uint32_t frame_id) {
  lost_frames_ = 0;
  if (!config_.enabled || config_.max_keyframes <= 0) return;
  for (const auto& k : keyframes_)
    if (within_spacing(config_, k->T_world_cam, T_world_cam)) return;
  std::unique_ptr<Keyframe> k = make_keyframe(m, T_world_cam, frame_id);
  if (!k) return;
  keyframes_.push_back(std::move(k));
  if (keyframes_.size() <= static_cast<size_t>(config_.max_keyframes)) return;
  // Full: the keyframe nearest to another goes (a metre counted as 45 degrees), so that the ones
  // left spread over where the camera has been, however long the scan.
  auto distance = [](const Keyframe& a, const Keyframe& b) {
    return (a.T_world_cam.translation() - b.T_world_cam.translation()).norm() +
           rotation_deg(a.T_world_cam, b.T_world_cam) / 45.0;
  };
  size_t drop = 0;
  double nearest = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < keyframes_.size(); ++i)
    for (size_t j = i + 1; j < keyframes_.size(); ++j) {
      const double d = distance(*keyframes_[i], *keyframes_[j]);
      if (d < nearest) {
        nearest = d;
        drop = i;  // the older of the two
      }
    }
  keyframes_.erase(keyframes_.begin() + static_cast<std::ptrdiff_t>(drop));
}

struct Relocaliser::FrameCloud {
  bool made = false;
  Cloud::Ptr cloud;
  Features::Ptr features;
};

std::optional<Pose> Relocaliser::try_keyframe(Keyframe& k, const MeasurementImage& m,
                                              FrameCloud* frame, const Verify& verify,
                                              unsigned seed) {
  // The keyframe's own pose first: a camera back near a keyframe is within ICP's reach from
  // there, and that costs one track; sample consensus is for a camera further off.
  if (std::optional<Pose> T = verify(k.T_world_cam)) return T;
  if (!frame->made) {
    frame->made = true;
    frame->cloud = downsample(m, config_);
    if (frame->cloud->size() >= kMinPoints)
      frame->features = describe(&frame->cloud, config_.feature_radius_m);
  }
  if (frame->cloud->size() < kMinPoints) return std::nullopt;
  if (!k.features) k.features = describe(&k.cloud, config_.feature_radius_m);
  if (k.cloud->size() < kMinPoints) return std::nullopt;
  const std::optional<Pose> T_kf_cam =
      sample_consensus(frame->cloud, frame->features, k.cloud, k.features, config_, seed);
  if (!T_kf_cam) return std::nullopt;
  return verify(k.T_world_cam * *T_kf_cam);
}

std::optional<Pose> Relocaliser::search(const MeasurementImage& m, const Verify& verify,
                                        bool* ambiguous) {
  *ambiguous = false;
  if (!config_.enabled || keyframes_.empty()) return std::nullopt;
  const int attempt = lost_frames_++;
  const int every = std::max(1, config_.every_n_lost_frames);
  if (attempt % every != 0) return std::nullopt;
  const int round = attempt / every;

  const Thumbnail thumb = make_thumbnail(m);
  std::vector<double> score(keyframes_.size());
  for (size_t i = 0; i < keyframes_.size(); ++i) score[i] = similarity(thumb, keyframes_[i]->thumbnail);
  std::vector<size_t> ranked(keyframes_.size());
  std::iota(ranked.begin(), ranked.end(), 0);
  std::stable_sort(ranked.begin(), ranked.end(), [&](size_t a, size_t b) { return score[a] > score[b]; });

  FrameCloud frame;
  const unsigned seed = static_cast<unsigned>(attempt) + 1u;
  // Every other try goes to the best-ranked keyframe, the others down the ranking: the thumbnail
  // is usually right, but not always.
  const size_t n = ranked.size();
  const size_t tries = std::min<size_t>(std::max(1, config_.candidates_per_frame), n);
  std::optional<Pose> found;
  size_t found_rank = 0;
  for (size_t t = 0; t < tries && !found; ++t) {
    const size_t a = static_cast<size_t>(round) * tries + t;
    found_rank = a % 2 == 0 || n == 1 ? 0 : 1 + (a / 2) % (n - 1);
    found = try_keyframe(*keyframes_[ranked[found_rank]], m, &frame, verify, seed);
  }
  if (!found) return std::nullopt;
  DF_LOG(Relocalisation, Debug) << "found at " << found->translation().transpose() << " by keyframe "
                                << keyframes_[ranked[found_rank]]->frame_id << " (rank " << found_rank
                                << " of " << n << ")";

  // A place is believed when it is the only one that fits. Rivals are the keyframes most alike
  // the frame that stand somewhere else: one that is verified too, away from the place found,
  // means the view fits both (look-alike rooms), and either may be wrong.
  int rivals = 0;
  for (size_t r = 0; r < n && rivals < config_.ambiguity_rivals; ++r) {
    Keyframe& k = *keyframes_[ranked[r]];
    if (r == found_rank ||
        (k.T_world_cam.translation() - found->translation()).norm() <= config_.ambiguity_m)
      continue;
    ++rivals;
    const std::optional<Pose> rival = try_keyframe(k, m, &frame, verify, seed);
    DF_LOG(Relocalisation, Debug) << "rival keyframe " << k.frame_id << " at "
                                  << k.T_world_cam.translation().transpose() << ": "
                                  << (rival ? "verified" : "not verified");
    if (rival && (rival->translation() - found->translation()).norm() > config_.ambiguity_m) {
      *ambiguous = true;
      return std::nullopt;
    }
  }
  return found;
}

}  // namespace depthfuse
