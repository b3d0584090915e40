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
  uint32_t last_frame = 0;   // id of the last frame that merged into it
};

// What fusion reads and writes together on every merge, in one 48-byte record: a merge then touches
// one or two cache lines instead of a dozen separate columns.
struct PointState {
  // Information matrix (inverse covariance) in 1/m^2, symmetric.
  float info_xx, info_xy, info_xz, info_yy, info_yz, info_zz;
  float nx, ny, nz;         // unit normal, world frame
  uint16_t merges;          // how many measurements refined this point
  uint16_t violations;      // how often a camera saw through it
  uint32_t last_frame;      // id of the last frame that merged into it
  uint8_t r, g, b;          // colour, 0 when the input has none
  uint8_t reserved;         // always 0
};
static_assert(sizeof(PointState) == 48, "PointState is one packed 48-byte record");

// The fused cloud's point data: two arrays, positions (what projecting the map into a camera
// streams through) and per-point state (what a merge updates). One PointArrays per map chunk; the
// same type carries exported and loaded clouds, so nothing converts between layouts.
struct PointArrays {
  std::vector<Eigen::Vector3f> position_m;  // world frame
  std::vector<PointState> state;

  size_t size() const { return position_m.size(); }
  bool empty() const { return position_m.empty(); }
  void reserve(size_t n);
  void clear();
  void resize(size_t n);
  void push_back(const PointRecord& p);
  // Grows by an eighth, not by the doubling std::vector would: the map's budget counts the
  // capacity its chunks hold, and a chunk loaded back (exactly its size) that takes in a few points
  // (fusion, or a loop closure moving its neighbours' points into it) would double at once.
  void push_back(const Eigen::Vector3f& position, const PointState& s) {
    if (position_m.size() == position_m.capacity()) reserve(size() + size() / 8 + 16);
    position_m.push_back(position);
    state.push_back(s);
  }
  PointRecord get(size_t i) const;
  void set(size_t i, const PointRecord& p);
  void append(const PointArrays& other);
  // Keeps the points whose keep[i] is non-zero, in order. Returns how many were removed.
  size_t compact(const std::vector<uint8_t>& keep);
  size_t memory_bytes() const;  // capacity actually held
  // Bit-exact comparison (NaN payloads and signed zeros included).
  bool operator==(const PointArrays& o) const;

  static constexpr size_t kBytesPerPoint = sizeof(Eigen::Vector3f) + sizeof(PointState);

  const Eigen::Vector3f& position(size_t i) const { return position_m[i]; }
  Eigen::Vector3f normal(size_t i) const { return {state[i].nx, state[i].ny, state[i].nz}; }
};

// The information matrix of point i as a full 3x3 matrix (reports, tests).
inline Eigen::Matrix3f information_matrix(const PointArrays& a, size_t i) {
  const PointState& s = a.state[i];
  Eigen::Matrix3f m;
  m << s.info_xx, s.info_xy, s.info_xz,
       s.info_xy, s.info_yy, s.info_yz,
       s.info_xz, s.info_yz, s.info_zz;
  return m;
}
// The trace of a point's covariance (the inverse of its information) as the sum of the
// information's diagonal cofactors over its determinant: no inverse is formed. Writes both; the
// information is singular where !(det > 0).
inline void covariance_trace_parts(const PointState& s, float* cofactor_sum, float* det) {
  const float c_xx = s.info_yy * s.info_zz - s.info_yz * s.info_yz;
  const float c_yy = s.info_xx * s.info_zz - s.info_xz * s.info_xz;
  const float c_zz = s.info_xx * s.info_yy - s.info_xy * s.info_xy;
  *det = s.info_xx * c_xx - s.info_xy * (s.info_xy * s.info_zz - s.info_yz * s.info_xz) +
         s.info_xz * (s.info_xy * s.info_yz - s.info_yy * s.info_xz);
  *cofactor_sum = c_xx + c_yy + c_zz;
}

// A scalar uncertainty for reports and export: sqrt of the mean covariance eigenvalue, in metres.
float uncertainty_m(const PointArrays& a, size_t i);

}  // namespace depthfuse
