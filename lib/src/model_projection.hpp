// Internal: the map rendered into a camera. Fusion and registration find a measurement's
// neighbours here instead of searching the cloud: only chunks near the frame's own measurements
// are projected, so the cost follows the frame, not the map.
#pragma once

#include <cstdint>
#include <vector>

#include "depthfuse/measurement.hpp"
#include "depthfuse/point_map.hpp"

#include <cmath>

namespace depthfuse {

// Pixel of a camera-frame point, or false outside the image. Rounds without libm.
inline bool project_to_pixel(float x, float y, float z, float fx, float fy, float cx, float cy,
                             int width, int height, int* u, int* v) {
  if (z <= 1e-3f) return false;
  const float inv_z = 1.0f / z;
  const float fu = fx * x * inv_z + cx + 0.5f, fv = fy * y * inv_z + cy + 0.5f;
  if (!(fu >= 0.0f && fv >= 0.0f && fu < static_cast<float>(width) && fv < static_cast<float>(height)))
    return false;
  *u = static_cast<int>(fu);
  *v = static_cast<int>(fv);
  return true;
}

class ModelProjection {
 public:
  // Chunks touched by the measurements seen from T_world_cam (sampled every `stride` pixels), and
  // the stretch of each ray just in front of the surface (0.9 to 1.0 of the range, where a seen-
  // through point would be), each dilated where a point lies within margin_m of a chunk face.
  void select_chunks(PointMap& map, const MeasurementImage& m, const Pose& T_world_cam,
                     float margin_m, int stride = 8);

  // Z-buffers the points of the selected chunks into the camera at T_world_cam.
  void render(const Pose& T_world_cam, const CameraIntrinsics& K);

  // After render(): per pixel, the confidence-weighted mean (weight 1 + merges) of every rendered
  // point within band_m behind the nearest one. Registration aligns to this consensus surface:
  // the nearest point alone is biased towards the camera wherever the cloud still has several
  // layers (poorly registered frames), and ICP would pull every camera towards itself.
  void average_surface(const Pose& T_world_cam, const CameraIntrinsics& K, float band_m);
  bool has_surface(size_t pixel) const { return surface_w_[pixel] > 0.0f; }
  Eigen::Vector3f surface_point(size_t pixel) const {
    return {surface_x_[pixel], surface_y_[pixel], surface_z_[pixel]};
  }
  Eigen::Vector3f surface_normal(size_t pixel) const {
    return {surface_nx_[pixel], surface_ny_[pixel], surface_nz_[pixel]};
  }

  bool empty_at(size_t pixel) const { return slot_[pixel] < 0; }
  // World position of the point rendered at a pixel, stored pixel-ordered so that neighbourhood
  // searches read contiguous memory instead of chasing points through chunks.
  Eigen::Vector3f position_at(size_t pixel) const {
    return {pos_x_[pixel], pos_y_[pixel], pos_z_[pixel]};
  }
  // One merge per point per frame: a point is rendered at exactly one pixel, so a flag suffices.
  bool taken_at(size_t pixel) const { return taken_[pixel] != 0; }
  void take(size_t pixel) { taken_[pixel] = 1; }
  PointArrays& points_at(size_t pixel) const { return chunks_[slot_[pixel]]->points; }
  uint32_t index_at(size_t pixel) const { return index_[pixel]; }
  float depth_at(size_t pixel) const { return depth_[pixel]; }
  size_t rendered_points() const { return rendered_; }
  const std::vector<Chunk*>& chunks() const { return chunks_; }

 private:
  std::vector<ChunkKey> keys_;          // scratch
  std::vector<Chunk*> chunks_;          // selected, existing, non-empty chunks
  std::vector<int32_t> slot_;           // per pixel: index into chunks_, -1 = nothing
  std::vector<uint32_t> index_;         // per pixel: point index within the chunk
  std::vector<float> depth_;            // per pixel: z of that point in the camera
  std::vector<float> pos_x_, pos_y_, pos_z_;  // per pixel: its world position
  std::vector<uint8_t> taken_;          // per pixel: merged with a measurement of this frame
  size_t rendered_ = 0;
  // average_surface(): world-frame mean point and unit normal per pixel, and the summed weight.
  std::vector<float> surface_x_, surface_y_, surface_z_, surface_nx_, surface_ny_, surface_nz_;
  std::vector<float> surface_w_;
};

}  // namespace depthfuse
