#include "model_projection.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <tuple>

namespace depthfuse {


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
      for (float f : {1.0f, 0.95f, 0.9f}) map.keys_near(R * (f * p_c) + t, margin_m, &keys_);
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
  pos_x_.resize(n);
  pos_y_.resize(n);
  pos_z_.resize(n);
  taken_.assign(n, 0);
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
      int u, v;
      if (!project_to_pixel(x, y, z, fx, fy, cx, cy, K.width, K.height, &u, &v)) continue;
      const size_t px = static_cast<size_t>(v) * K.width + u;
      ++rendered_;
      if (z < depth_[px]) {
        depth_[px] = z;
        slot_[px] = static_cast<int32_t>(s);
        index_[px] = static_cast<uint32_t>(i);
        pos_x_[px] = a.x[i];
        pos_y_[px] = a.y[i];
        pos_z_[px] = a.z[i];
      }
    }
  }
}

void ModelProjection::average_surface(const Pose& T_world_cam, const CameraIntrinsics& K,
                                      float band_m) {
  const size_t n = static_cast<size_t>(K.width) * K.height;
  for (auto* v : {&surface_x_, &surface_y_, &surface_z_, &surface_nx_, &surface_ny_, &surface_nz_,
                  &surface_w_})
    v->assign(n, 0.0f);
  const Pose T_cam_world = T_world_cam.inverse();
  const Eigen::Matrix3f R = T_cam_world.linear().cast<float>();
  const Eigen::Vector3f t = T_cam_world.translation().cast<float>();
  const float fx = static_cast<float>(K.fx), fy = static_cast<float>(K.fy);
  const float cx = static_cast<float>(K.cx), cy = static_cast<float>(K.cy);
  for (const Chunk* c : chunks_) {
    const PointArrays& a = c->points;
    for (size_t i = 0; i < a.size(); ++i) {
      const float x = R(0, 0) * a.x[i] + R(0, 1) * a.y[i] + R(0, 2) * a.z[i] + t.x();
      const float y = R(1, 0) * a.x[i] + R(1, 1) * a.y[i] + R(1, 2) * a.z[i] + t.y();
      const float z = R(2, 0) * a.x[i] + R(2, 1) * a.y[i] + R(2, 2) * a.z[i] + t.z();
      int u, v;
      if (!project_to_pixel(x, y, z, fx, fy, cx, cy, K.width, K.height, &u, &v)) continue;
      const size_t px = static_cast<size_t>(v) * K.width + u;
      if (z > depth_[px] + band_m) continue;
      const float w = 1.0f + a.merges[i];
      surface_x_[px] += w * a.x[i];
      surface_y_[px] += w * a.y[i];
      surface_z_[px] += w * a.z[i];
      surface_nx_[px] += w * a.nx[i];
      surface_ny_[px] += w * a.ny[i];
      surface_nz_[px] += w * a.nz[i];
      surface_w_[px] += w;
    }
  }
  for (size_t px = 0; px < n; ++px) {
    const float w = surface_w_[px];
    if (w <= 0.0f) continue;
    surface_x_[px] /= w;
    surface_y_[px] /= w;
    surface_z_[px] /= w;
    Eigen::Vector3f nn(surface_nx_[px], surface_ny_[px], surface_nz_[px]);
    const float len = nn.norm();
    if (len < 0.5f * w) {  // normals disagree: no usable plane here
      surface_w_[px] = 0.0f;
      continue;
    }
    nn /= len;
    surface_nx_[px] = nn.x();
    surface_ny_[px] = nn.y();
    surface_nz_[px] = nn.z();
  }
}

}  // namespace depthfuse
