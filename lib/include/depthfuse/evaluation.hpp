// The paper's figures for a reconstruction: point-to-truth distances as a cumulative curve, the
// Jaccard index at several voxel sizes, the compression ratio.
#pragma once

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "depthfuse/point_arrays.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse {

struct DistanceSummary {
  size_t points = 0;
  double mean_m = 0, median_m = 0, p90_m = 0, p95_m = 0, max_m = 0;
  double within_5mm = 0;  // fraction of points within 5 mm of the truth
  std::vector<double> sorted_m;  // every distance, ascending (the cumulative curve)
};

DistanceSummary summarize_distances(std::vector<double> distances_m);

// Distances to the nearest point of a reference cloud, through a voxel hash (no kd-tree over the
// whole cloud per query): searched up to max_m, farther points report max_m.
std::vector<double> distances_to_cloud(const PointArrays& points, const PointArrays& reference,
                                       double max_m = 0.1);

// |A ∩ B| / |A ∪ B| over voxels of edge voxel_m occupied by each cloud.
double jaccard_index(const PointArrays& reconstruction, const PointArrays& truth, double voxel_m);

// Keeps one point per voxel (the first): for sampling a ground-truth surface at a fixed density.
PointArrays voxel_downsample(const PointArrays& points, double voxel_m);

// voxel_downsample of a concatenation, built a part at a time, in time linear in the points: a
// ground truth sampled from every frame of a long scan. Keeps each voxel's first point, in order.
class VoxelSampler {
 public:
  explicit VoxelSampler(double voxel_m);
  ~VoxelSampler();
  VoxelSampler(const VoxelSampler&) = delete;
  VoxelSampler& operator=(const VoxelSampler&) = delete;

  void add(const PointArrays& points);
  size_t size() const { return kept_.size(); }
  PointArrays take() { return std::move(kept_); }

 private:
  struct Seen;  // the occupied voxels
  double inv_voxel_;
  std::unique_ptr<Seen> seen_;
  PointArrays kept_;
};

// The share of the summarised points whose error is at most error_m: the cumulative curve.
double fraction_within(const DistanceSummary& s, double error_m);

}  // namespace depthfuse
