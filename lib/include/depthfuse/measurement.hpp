// A depth frame back-projected into camera-frame points with normals, and the paper's pre-filter.
#pragma once

#include <cstdint>
#include <vector>

#include "depthfuse/config.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse {

// Per-pixel structure-of-arrays; reused from frame to frame (resize only when the size changes).
struct MeasurementImage {
  int width = 0;
  int height = 0;
  CameraIntrinsics intrinsics;
  std::vector<float> x, y, z;     // camera frame, metres; z == depth
  std::vector<float> nx, ny, nz;  // unit normal facing the camera; 0 when unknown
  std::vector<uint8_t> valid;     // 1 = usable measurement

  size_t pixel_count() const { return x.size(); }
  size_t valid_count() const;
  void resize(int w, int h);
};

// Back-projects a depth frame (depth outside [min_depth_m, max_depth_m] is invalid) and computes
// normals by central differences. Fails on a frame whose size disagrees with its intrinsics.
Status backproject(const Frame& frame, const SensorModelConfig& sensor, const FusionConfig& fusion,
                   MeasurementImage* out);

// d_r(z) / z for these intrinsics: the mean distance from a point to its k-th nearest neighbour
// on a fronto-parallel plane at 1 m, found by back-projecting a constant depth map (d_r is linear
// in z for a pinhole camera).
double reference_knn_distance_per_m(const CameraIntrinsics& intrinsics, int neighbour_rank,
                                    int window_radius_px);

// The paper's pre-filter (eq. 1). Marks removed measurements invalid; returns how many. With two
// threads the two halves of the rows are tested at once; the result is the same.
size_t prefilter(const PrefilterConfig& config, MeasurementImage* m, int threads = 1);

}  // namespace depthfuse
