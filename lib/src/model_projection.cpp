#include "model_projection.hpp"

#include <algorithm>
#include <cstring>
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

namespace {

constexpr uint64_t kNoKey = ~uint64_t{0};
constexpr uint32_t kInfBits = 0x7f800000u;  // bit pattern of +inf

inline uint32_t float_bits(float f) {
  uint32_t b;
  std::memcpy(&b, &f, sizeof(b));
  return b;
}

inline float bits_float(uint32_t b) {
  float f;
  std::memcpy(&f, &b, sizeof(f));
  return f;
}

}  // namespace

template <bool kGuided>
void ModelProjection::render_points(const Pose& T_world_cam, const CameraIntrinsics& K) {
  const Pose T_cam_world = T_world_cam.inverse();
  const Eigen::Matrix3f R = T_cam_world.linear().cast<float>();
  const Eigen::Vector3f t = T_cam_world.translation().cast<float>();
  const float fx = static_cast<float>(K.fx), fy = static_cast<float>(K.fy);
  const float cx = static_cast<float>(K.cx), cy = static_cast<float>(K.cy);
  PixelKeys* keys = pixel_keys_.data();
  size_t rendered = 0;
  for (size_t s = 0; s < chunks_.size(); ++s) {
    const PointArrays& a = chunks_[s]->points;
    const size_t count = a.size();
    const float* px_ = a.x.data();
    const float* py_ = a.y.data();
    const float* pz_ = a.z.data();
    const uint64_t base = offsets_[s];
    for (size_t i = 0; i < count; ++i) {
      const float x = R(0, 0) * px_[i] + R(0, 1) * py_[i] + R(0, 2) * pz_[i] + t.x();
      const float y = R(1, 0) * px_[i] + R(1, 1) * py_[i] + R(1, 2) * pz_[i] + t.y();
      const float z = R(2, 0) * px_[i] + R(2, 1) * py_[i] + R(2, 2) * pz_[i] + t.z();
      int u, v;
      if (!project_to_pixel(x, y, z, fx, fy, cx, cy, K.width, K.height, &u, &v)) continue;
      PixelKeys& k = keys[static_cast<size_t>(v) * K.width + u];
      ++rendered;
      const uint64_t id = base + i;
      const uint64_t front = (uint64_t{float_bits(z)} << 32) | id;
      // Branch-free minimum: which point wins a pixel is unpredictable.
      k.front = std::min(front, k.front);
      if (kGuided) {
        // Pixels without a measurement have measured_z = +inf: their keys stay at the maximum.
        const uint64_t cand = (uint64_t{float_bits(std::abs(z - k.measured_z))} << 32) | id;
        k.cand = std::min(cand, k.cand);
      }
    }
  }
  rendered_ = rendered;
}

void ModelProjection::locate(uint32_t id, int32_t* slot, uint32_t* index) const {
  // Neighbouring pixels mostly hit the chunk of the last lookup (*slot on entry, if valid).
  size_t s = static_cast<size_t>(*slot);
  if (*slot < 0 || s + 1 >= offsets_.size() || id < offsets_[s] || id >= offsets_[s + 1]) {
    const auto it = std::upper_bound(offsets_.begin(), offsets_.end(), id);
    s = static_cast<size_t>(it - offsets_.begin()) - 1;
  }
  *slot = static_cast<int32_t>(s);
  *index = id - offsets_[s];
}

void ModelProjection::render(const Pose& T_world_cam, const CameraIntrinsics& K,
                             const MeasurementImage* measured) {
  const size_t n = static_cast<size_t>(K.width) * K.height;
  offsets_.resize(chunks_.size() + 1);
  uint64_t total = 0;
  for (size_t s = 0; s < chunks_.size(); ++s) {
    offsets_[s] = static_cast<uint32_t>(total);
    total += chunks_[s]->points.size();
  }
  // More points than ids would mean a map of billions of points in view; render a prefix only.
  if (total >= 0xffffffffull) {
    size_t keep = 0;
    uint64_t sum = 0;
    while (keep < chunks_.size() && sum + chunks_[keep]->points.size() < 0xffffffffull)
      sum += chunks_[keep++]->points.size();
    chunks_.resize(keep);
    offsets_.resize(keep + 1);
    total = sum;
  }
  offsets_[chunks_.size()] = static_cast<uint32_t>(total);

  const bool guided = measured && measured->pixel_count() == n;
  pixel_keys_.resize(n);
  for (size_t px = 0; px < n; ++px) {
    PixelKeys& k = pixel_keys_[px];
    k.front = kNoKey;
    k.cand = kNoKey;
    k.measured_z = guided && measured->valid[px] ? measured->z[px]
                                                 : std::numeric_limits<float>::infinity();
  }
  if (guided) {
    render_points<true>(T_world_cam, K);
  } else {
    render_points<false>(T_world_cam, K);
  }

  front_slot_.resize(n);
  front_index_.resize(n);
  front_depth_.resize(n);
  cand_slot_.resize(n);
  cand_index_.resize(n);
  cand_x_.resize(n);
  cand_y_.resize(n);
  cand_z_.resize(n);
  taken_.assign(n, 0);
  int32_t front_hint = -1, cand_hint = -1;
  for (size_t px = 0; px < n; ++px) {
    const PixelKeys& k = pixel_keys_[px];
    if (k.front == kNoKey) {
      front_slot_[px] = -1;
      front_depth_[px] = std::numeric_limits<float>::infinity();
    } else {
      locate(static_cast<uint32_t>(k.front), &front_hint, &front_index_[px]);
      front_slot_[px] = front_hint;
      front_depth_[px] = bits_float(static_cast<uint32_t>(k.front >> 32));
    }
    if ((k.cand >> 32) >= kInfBits) {  // no candidate, or no measurement at this pixel
      cand_slot_[px] = -1;
      continue;
    }
    locate(static_cast<uint32_t>(k.cand), &cand_hint, &cand_index_[px]);
    const int32_t slot = cand_hint;
    const uint32_t index = cand_index_[px];
    cand_slot_[px] = slot;
    const PointArrays& a = chunks_[slot]->points;
    cand_x_[px] = a.x[index];
    cand_y_[px] = a.y[index];
    cand_z_[px] = a.z[index];
  }
}

void ModelProjection::average_surface(const Pose& T_world_cam, const CameraIntrinsics& K,
                                      float band_m) {
  const size_t n = static_cast<size_t>(K.width) * K.height;
  surface_.assign(n, SurfaceSum{0, 0, 0, 0, 0, 0, 0});
  const Pose T_cam_world = T_world_cam.inverse();
  const Eigen::Matrix3f R = T_cam_world.linear().cast<float>();
  const Eigen::Vector3f t = T_cam_world.translation().cast<float>();
  const float fx = static_cast<float>(K.fx), fy = static_cast<float>(K.fy);
  const float cx = static_cast<float>(K.cx), cy = static_cast<float>(K.cy);
  const float* depth = front_depth_.data();
  SurfaceSum* sum = surface_.data();
  for (const Chunk* c : chunks_) {
    const PointArrays& a = c->points;
    const size_t count = a.size();
    for (size_t i = 0; i < count; ++i) {
      const float x = R(0, 0) * a.x[i] + R(0, 1) * a.y[i] + R(0, 2) * a.z[i] + t.x();
      const float y = R(1, 0) * a.x[i] + R(1, 1) * a.y[i] + R(1, 2) * a.z[i] + t.y();
      const float z = R(2, 0) * a.x[i] + R(2, 1) * a.y[i] + R(2, 2) * a.z[i] + t.z();
      int u, v;
      if (!project_to_pixel(x, y, z, fx, fy, cx, cy, K.width, K.height, &u, &v)) continue;
      const size_t px = static_cast<size_t>(v) * K.width + u;
      if (z > depth[px] + band_m) continue;
      const float w = 1.0f + a.merges[i];
      SurfaceSum& s = sum[px];
      s.x += w * a.x[i];
      s.y += w * a.y[i];
      s.z += w * a.z[i];
      s.nx += w * a.nx[i];
      s.ny += w * a.ny[i];
      s.nz += w * a.nz[i];
      s.w += w;
    }
  }
  for (size_t px = 0; px < n; ++px) {
    SurfaceSum& s = sum[px];
    if (s.w <= 0.0f) continue;
    const float inv_w = 1.0f / s.w;
    s.x *= inv_w;
    s.y *= inv_w;
    s.z *= inv_w;
    Eigen::Vector3f nn(s.nx, s.ny, s.nz);
    const float len = nn.norm();
    if (len < 0.5f * s.w) {  // normals disagree: no usable plane here
      s.w = 0.0f;
      continue;
    }
    nn /= len;
    s.nx = nn.x();
    s.ny = nn.y();
    s.nz = nn.z();
  }
}

}  // namespace depthfuse
