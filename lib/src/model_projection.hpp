// Internal: the map rendered into a camera. Fusion and registration find a measurement's
// neighbours here instead of searching the cloud: only chunks near the frame's own measurements
// are projected, so the cost follows the frame, not the map.
#pragma once

#include <cstdint>
#include <vector>

#include "depthfuse/measurement.hpp"
#include "depthfuse/point_map.hpp"

namespace depthfuse {

class ModelProjection {
 public:
  // Chunks touched by the measurements seen from T_world_cam (sampled every `stride` pixels), and
  // the stretch of each ray just in front of the surface (0.9 to 1.0 of the range, where a seen-
  // through point would be), each dilated where a point lies within margin_m of a chunk face.
  void select_chunks(PointMap& map, const MeasurementImage& m, const Pose& T_world_cam,
                     float margin_m, int stride = 8);

  // Z-buffers the points of the selected chunks into the camera at T_world_cam.
  void render(const Pose& T_world_cam, const CameraIntrinsics& K);

  bool empty_at(size_t pixel) const { return slot_[pixel] < 0; }
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
  size_t rendered_ = 0;
};

}  // namespace depthfuse
