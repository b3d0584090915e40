#include "depthfuse/evaluation.hpp"

#include <algorithm>
#include <cmath>
#include <unordered_map>
#include <unordered_set>

#include "depthfuse/point_map.hpp"

namespace depthfuse {

namespace {

inline ChunkKey voxel(const Eigen::Vector3f& p, double inv) {
  const float x = p.x(), y = p.y(), z = p.z();
  return {static_cast<int32_t>(std::floor(x * inv)), static_cast<int32_t>(std::floor(y * inv)),
          static_cast<int32_t>(std::floor(z * inv))};
}

std::unordered_set<ChunkKey, ChunkKeyHash> voxel_set(const PointArrays& a, double voxel_m) {
  std::unordered_set<ChunkKey, ChunkKeyHash> s;
  s.reserve(a.size() / 4 + 16);
  const double inv = 1.0 / voxel_m;
  for (size_t i = 0; i < a.size(); ++i) s.insert(voxel(a.position_m[i], inv));
  return s;
}

}  // namespace

DistanceSummary summarize_distances(std::vector<double> d) {
  DistanceSummary s;
  std::sort(d.begin(), d.end());
  s.points = d.size();
  if (d.empty()) return s;
  double sum = 0;
  size_t within = 0;
  for (double v : d) {
    sum += v;
    within += v <= 0.005;
  }
  auto q = [&d](double f) { return d[std::min(d.size() - 1, static_cast<size_t>(f * (d.size() - 1) + 0.5))]; };
  s.mean_m = sum / d.size();
  s.median_m = q(0.5);
  s.p90_m = q(0.9);
  s.p95_m = q(0.95);
  s.max_m = d.back();
  s.within_5mm = static_cast<double>(within) / d.size();
  s.sorted_m = std::move(d);
  return s;
}

std::vector<double> distances_to_cloud(const PointArrays& points, const PointArrays& ref, double max_m) {
  // Buckets of the reference at cell = max_m / 4; rings of cells searched outwards.
  const double cell = max_m / 4;
  const double inv = 1.0 / cell;
  std::unordered_map<ChunkKey, std::vector<uint32_t>, ChunkKeyHash> grid;
  grid.reserve(ref.size() / 8 + 16);
  for (size_t i = 0; i < ref.size(); ++i) grid[voxel(ref.position_m[i], inv)].push_back(static_cast<uint32_t>(i));
  std::vector<double> out(points.size(), max_m);
  for (size_t i = 0; i < points.size(); ++i) {
    const ChunkKey c = voxel(points.position_m[i], inv);
    double best2 = max_m * max_m;
    for (int ring = 0; ring <= 4; ++ring) {
      // Once a hit closer than the ring's inner distance is found, outer rings cannot beat it.
      if (ring > 0 && best2 <= std::pow((ring - 1) * cell, 2)) break;
      for (int dx = -ring; dx <= ring; ++dx)
        for (int dy = -ring; dy <= ring; ++dy)
          for (int dz = -ring; dz <= ring; ++dz) {
            if (std::max({std::abs(dx), std::abs(dy), std::abs(dz)}) != ring) continue;
            auto it = grid.find({c.x + dx, c.y + dy, c.z + dz});
            if (it == grid.end()) continue;
            for (uint32_t j : it->second) {
              const Eigen::Vector3d e = (points.position_m[i] - ref.position_m[j]).cast<double>();
              best2 = std::min(best2, e.squaredNorm());
            }
          }
    }
    out[i] = std::sqrt(best2);
  }
  return out;
}

double jaccard_index(const PointArrays& rec, const PointArrays& truth, double voxel_m) {
  const auto a = voxel_set(rec, voxel_m);
  const auto b = voxel_set(truth, voxel_m);
  size_t inter = 0;
  for (const auto& k : a) inter += b.count(k);
  const size_t uni = a.size() + b.size() - inter;
  return uni ? static_cast<double>(inter) / uni : 0.0;
}

struct VoxelSampler::Seen {
  std::unordered_set<ChunkKey, ChunkKeyHash> voxels;
};

VoxelSampler::VoxelSampler(double voxel_m)
    : inv_voxel_(1.0 / voxel_m), seen_(std::make_unique<Seen>()) {}

VoxelSampler::~VoxelSampler() = default;

void VoxelSampler::add(const PointArrays& a) {
  for (size_t i = 0; i < a.size(); ++i)
    if (seen_->voxels.insert(voxel(a.position_m[i], inv_voxel_)).second) kept_.push_back(a.get(i));
}

PointArrays voxel_downsample(const PointArrays& a, double voxel_m) {
  VoxelSampler sampler(voxel_m);
  sampler.add(a);
  return sampler.take();
}

double fraction_within(const DistanceSummary& s, double error_m) {
  if (s.sorted_m.empty()) return 0;
  const auto end = std::upper_bound(s.sorted_m.begin(), s.sorted_m.end(), error_m);
  return static_cast<double>(end - s.sorted_m.begin()) / s.sorted_m.size();
}

}  // namespace depthfuse
