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

namespace depthfuse {

namespace {

using Cloud = pcl::PointCloud<pcl::PointNormal>;
using Features = pcl::PointCloud<pcl::FPFHSignature33>;

// The global descriptor that ranks keyframes: the frame's depth averaged over a coarse grid (a
// "small blurry image", as PTAM's relocaliser uses). Cheap to compare against every keyframe on
// every lost frame; it only orders the candidates, sample consensus and ICP decide.
constexpr int kThumbW = 16, kThumbH = 12;
using Thumbnail = std::array<float, kThumbW * kThumbH>;  // mean depth, m; 0: no measurement

Thumbnail make_thumbnail(const MeasurementImage& m) {
  std::array<float, kThumbW * kThumbH> sum{};
  std::array<int, kThumbW * kThumbH> count{};
  constexpr int kStep = 4;  // every 4th pixel in u and v is plenty for a 16 x 12 average
  for (int v = 0; v < m.height; v += kStep) {
    const int tv = v * kThumbH / m.height;
    for (int u = 0; u < m.width; u += kStep) {
      const size_t i = static_cast<size_t>(v) * m.width + u;
      if (!m.valid[i]) continue;
      const int t = tv * kThumbW + u * kThumbW / m.width;
      sum[t] += m.z[i];
      ++count[t];
    }
  }
  Thumbnail out{};
  for (size_t t = 0; t < out.size(); ++t) out[t] = count[t] ? sum[t] / count[t] : 0.0f;
  return out;
}

// Zero-mean normalised cross-correlation of the cells both thumbnails have, times the share of
// cells either has that both have: in [-1, 1], higher is more alike.
double similarity(const Thumbnail& a, const Thumbnail& b) {
  double ma = 0, mb = 0;
  int both = 0, either = 0;
  for (size_t t = 0; t < a.size(); ++t) {
    either += (a[t] > 0) || (b[t] > 0);
    if (a[t] > 0 && b[t] > 0) {
      ma += a[t];
      mb += b[t];
      ++both;
    }
  }
  if (both < 8) return -1.0;
  ma /= both;
  mb /= both;
  double sab = 0, saa = 0, sbb = 0;
  for (size_t t = 0; t < a.size(); ++t) {
    if (!(a[t] > 0 && b[t] > 0)) continue;
    const double da = a[t] - ma, db = b[t] - mb;
    sab += da * db;
    saa += da * da;
    sbb += db * db;
  }
  const double ncc = saa > 0 && sbb > 0 ? sab / std::sqrt(saa * sbb) : 0.0;
  return ncc * both / either;
}

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

}  // namespace

struct Relocaliser::Keyframe {
  Pose T_world_cam;
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
                                                                  const Pose& T_world_cam) const {
  auto k = std::make_unique<Keyframe>();
  k->T_world_cam = T_world_cam;
  k->thumbnail = make_thumbnail(m);
  k->cloud = downsample(m, config_);
  if (k->cloud->size() < kMinPoints) return nullptr;
  return k;
}

bool Relocaliser::add_older_keyframe(const MeasurementImage& m, const Pose& T_world_cam) {
  if (!wants(T_world_cam)) return false;
  std::unique_ptr<Keyframe> k = make_keyframe(m, T_world_cam);
  if (!k) return false;
  keyframes_.insert(keyframes_.begin(), std::move(k));
  return true;
}

void Relocaliser::frame_tracked(const MeasurementImage& m, const Pose& T_world_cam) {
  lost_frames_ = 0;
  if (!config_.enabled || config_.max_keyframes <= 0) return;
  for (const auto& k : keyframes_)
    if (within_spacing(config_, k->T_world_cam, T_world_cam)) return;
  std::unique_ptr<Keyframe> k = make_keyframe(m, T_world_cam);
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

std::optional<Pose> Relocaliser::search(const MeasurementImage& m,
                                        const std::function<bool(const Pose&)>& verify) {
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

  Cloud::Ptr cloud;  // the frame's points and features, made once the first keyframe needs them
  Features::Ptr features;
  // Every other try goes to the best-ranked keyframe, the others down the ranking: the thumbnail
  // is usually right, but not always.
  const size_t n = ranked.size();
  const size_t tries = std::min<size_t>(std::max(1, config_.candidates_per_frame), n);
  for (size_t t = 0; t < tries; ++t) {
    const size_t a = static_cast<size_t>(round) * tries + t;
    const size_t rank = a % 2 == 0 || n == 1 ? 0 : 1 + (a / 2) % (n - 1);
    Keyframe& k = *keyframes_[ranked[rank]];
    // The keyframe's own pose first: a camera back near a keyframe is within ICP's reach from
    // there, and that costs one track; sample consensus is for a camera further off.
    if (verify(k.T_world_cam)) return k.T_world_cam;
    if (!cloud) {
      cloud = downsample(m, config_);
      if (cloud->size() < kMinPoints) return std::nullopt;
      features = describe(&cloud, config_.feature_radius_m);
      if (cloud->size() < kMinPoints) return std::nullopt;
    }
    if (!k.features) k.features = describe(&k.cloud, config_.feature_radius_m);
    if (k.cloud->size() < kMinPoints) continue;
    pcl::SampleConsensusPrerejective<pcl::PointNormal, pcl::PointNormal, pcl::FPFHSignature33> sac;
    sac.setInputSource(cloud);
    sac.setSourceFeatures(features);
    sac.setInputTarget(k.cloud);
    sac.setTargetFeatures(k.features);
    sac.setMaximumIterations(config_.sac_iterations);
    sac.setNumberOfSamples(3);
    sac.setCorrespondenceRandomness(2);  // one of the 2 nearest features, not always the nearest
    sac.setSimilarityThreshold(0.9f);    // the sample's edge lengths must agree to 10 %
    sac.setMaxCorrespondenceDistance(config_.sac_inlier_m);
    sac.setInlierFraction(static_cast<float>(config_.sac_inlier_fraction));
    // PCL draws its samples with rand(): seeded here so that a run can be repeated.
    std::srand(static_cast<unsigned>(attempt) + 1u);
    Cloud aligned;
    sac.align(aligned);
    if (!sac.hasConverged()) continue;
    Pose T_kf_cam = Pose::Identity();
    T_kf_cam.matrix() = sac.getFinalTransformation().cast<double>();
    const Pose T_world_cam = k.T_world_cam * T_kf_cam;
    if (verify(T_world_cam)) return T_world_cam;
  }
  return std::nullopt;
}

}  // namespace depthfuse
