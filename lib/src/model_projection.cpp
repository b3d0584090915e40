#include "model_projection.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <tuple>

namespace depthfuse {

namespace {

inline void push_dilated(const PointMap& map, const Eigen::Vector3f& p, float margin,
                         std::vector<ChunkKey>* keys) {
  const ChunkKey k = map.key_for(p);
  keys->push_back(k);
  const Eigen::Vector3f o = map.chunk_origin_m(k);
  const float s = static_cast<float>(map.chunk_size_m());
  int lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    const float f = p[a] - o[a];
    lo[a] = f < margin ? -1 : 0;
    hi[a] = f > s - margin ? 1 : 0;
  }
  for (int dx = lo[0]; dx <= hi[0]; ++dx)
    for (int dy = lo[1]; dy <= hi[1]; ++dy)
      for (int dz = lo[2]; dz <= hi[2]; ++dz)
        if (dx || dy || dz) keys->push_back({k.x + dx, k.y + dy, k.z + dz});
}

}  // namespace

void ModelProjection::select_chunks(PointMap& map, const MeasurementImage& m,
                                    const Pose& T_world_cam, float margin_m, int stride) {
  keys_.clear();
  const Eigen::Matrix3f R = T_world_cam.linear().cast<float>();
  const Eigen::Vector3f t = T_world_cam.translation().cast<float>();
  for (int v = stride / 2; v < m.height; v += stride) {
    for (int u = stride / 2; u < m.width; u += stride) {
      const size_t i = static_cast<size_t>(v) * m.width + u;
      if (!m.valid[i]) continue;
      const Eigen::Vector3f p_c(m.x[i], m.y[i], m.z[i]);
      for (float f : {1.0f, 0.95f, 0.9f}) push_dilated(map, R * (f * p_c) + t, margin_m, &keys_);
    }
  }
  std::sort(keys_.begin(), keys_.end(), [](const ChunkKey& a, const ChunkKey& b) {
    return std::tie(a.x, a.y, a.z) < std::tie(b.x, b.y, b.z);
  });
  keys_.erase(std::unique(keys_.begin(), keys_.end()), keys_.end());
  chunks_.clear();
  for (const ChunkKey& k : keys_) {
    if (Chunk* c = map.find(k)) {
      if (!c->points.empty()) chunks_.push_back(c);
    }
  }
}

void ModelProjection::render(const Pose& T_world_cam, const CameraIntrinsics& K) {
  const size_t n = static_cast<size_t>(K.width) * K.height;
  slot_.assign(n, -1);
  index_.resize(n);
  depth_.assign(n, std::numeric_limits<float>::infinity());
  rendered_ = 0;
  const Pose T_cam_world = T_world_cam.inverse();
  const Eigen::Matrix3f R = T_cam_world.linear().cast<float>();
  const Eigen::Vector3f t = T_cam_world.translation().cast<float>();
  const float fx = static_cast<float>(K.fx), fy = static_cast<float>(K.fy);
  const float cx = static_cast<float>(K.cx), cy = static_cast<float>(K.cy);
  for (size_t s = 0; s < chunks_.size(); ++s) {
    const PointArrays& a = chunks_[s]->points;
    const size_t count = a.size();
    for (size_t i = 0; i < count; ++i) {
      const float x = R(0, 0) * a.x[i] + R(0, 1) * a.y[i] + R(0, 2) * a.z[i] + t.x();
      const float y = R(1, 0) * a.x[i] + R(1, 1) * a.y[i] + R(1, 2) * a.z[i] + t.y();
      const float z = R(2, 0) * a.x[i] + R(2, 1) * a.y[i] + R(2, 2) * a.z[i] + t.z();
      if (z <= 1e-3f) continue;
      const float inv_z = 1.0f / z;
      const int u = static_cast<int>(std::lround(fx * x * inv_z + cx));
      const int v = static_cast<int>(std::lround(fy * y * inv_z + cy));
      if (u < 0 || v < 0 || u >= K.width || v >= K.height) continue;
      const size_t px = static_cast<size_t>(v) * K.width + u;
      ++rendered_;
      if (z < depth_[px]) {
        depth_[px] = z;
        slot_[px] = static_cast<int32_t>(s);
        index_[px] = static_cast<uint32_t>(i);
      }
    }
  }
}

}  // namespace depthfuse
