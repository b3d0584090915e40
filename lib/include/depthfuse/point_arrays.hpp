// The fused cloud's point data as structure-of-arrays. One PointArrays per map chunk; the same type
// carries exported and loaded clouds, so nothing converts between layouts.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include <Eigen/Core>

namespace depthfuse {

// One point, used only at the edges (adding a point, tests, I/O); hot loops use the arrays.
struct PointRecord {
  Eigen::Vector3f position_m = Eigen::Vector3f::Zero();      // world frame
  Eigen::Vector3f normal = Eigen::Vector3f::UnitZ();          // unit, world frame
  // Information matrix (inverse covariance) in 1/m^2, symmetric: xx xy xz yy yz zz.
  float information[6] = {0, 0, 0, 0, 0, 0};
  uint8_t rgb[3] = {0, 0, 0};
  uint16_t merges = 0;       // how many measurements refined this point
  uint16_t violations = 0;   // how often a camera saw through it
  uint32_t last_frame = 0;   // id of the last frame that merged into it (one merge per frame)
};

struct PointArrays {
  std::vector<float> x, y, z;
  std::vector<float> nx, ny, nz;
  std::vector<float> info_xx, info_xy, info_xz, info_yy, info_yz, info_zz;
  std::vector<uint8_t> r, g, b;
  std::vector<uint16_t> merges, violations;
  std::vector<uint32_t> last_frame;

  size_t size() const { return x.size(); }
  bool empty() const { return x.empty(); }
  void reserve(size_t n);
  void clear();
  void push_back(const PointRecord& p);
  PointRecord get(size_t i) const;
  void set(size_t i, const PointRecord& p);
  void append(const PointArrays& other);
  // Keeps the points whose keep[i] is non-zero, in order. Returns how many were removed.
  size_t compact(const std::vector<uint8_t>& keep);
  size_t memory_bytes() const;  // capacity actually held
  bool operator==(const PointArrays& o) const;

  static constexpr size_t kBytesPerPoint = 6 * 4 + 6 * 4 + 3 + 2 * 2 + 4;

  Eigen::Vector3f position(size_t i) const { return {x[i], y[i], z[i]}; }
  Eigen::Vector3f normal(size_t i) const { return {nx[i], ny[i], nz[i]}; }
};

// Information matrix helpers (symmetric 3x3 stored as 6 floats).
inline Eigen::Matrix3f information_matrix(const PointArrays& a, size_t i) {
  Eigen::Matrix3f m;
  m << a.info_xx[i], a.info_xy[i], a.info_xz[i],
       a.info_xy[i], a.info_yy[i], a.info_yz[i],
       a.info_xz[i], a.info_yz[i], a.info_zz[i];
  return m;
}
inline void set_information(PointArrays& a, size_t i, const Eigen::Matrix3f& m) {
  a.info_xx[i] = m(0, 0); a.info_xy[i] = m(0, 1); a.info_xz[i] = m(0, 2);
  a.info_yy[i] = m(1, 1); a.info_yz[i] = m(1, 2); a.info_zz[i] = m(2, 2);
}

// A scalar uncertainty for reports and export: sqrt of the mean covariance eigenvalue, in metres.
float uncertainty_m(const PointArrays& a, size_t i);

}  // namespace depthfuse
