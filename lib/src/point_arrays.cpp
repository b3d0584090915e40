#include "depthfuse/point_arrays.hpp"

#include <cmath>
#include <cstring>
#include <limits>

#include <Eigen/LU>

namespace depthfuse {

void PointArrays::reserve(size_t n) {
  position_m.reserve(n);
  state.reserve(n);
}

void PointArrays::clear() {
  position_m.clear();
  state.clear();
}

void PointArrays::resize(size_t n) {
  position_m.resize(n, Eigen::Vector3f::Zero());
  state.resize(n, PointState{});
}

namespace {

PointState state_of(const PointRecord& p) {
  PointState s{};
  s.info_xx = p.information[0]; s.info_xy = p.information[1]; s.info_xz = p.information[2];
  s.info_yy = p.information[3]; s.info_yz = p.information[4]; s.info_zz = p.information[5];
  s.nx = p.normal.x(); s.ny = p.normal.y(); s.nz = p.normal.z();
  s.merges = p.merges;
  s.violations = p.violations;
  s.last_frame = p.last_frame;
  s.r = p.rgb[0]; s.g = p.rgb[1]; s.b = p.rgb[2];
  return s;
}

}  // namespace

void PointArrays::push_back(const PointRecord& p) { push_back(p.position_m, state_of(p)); }

PointRecord PointArrays::get(size_t i) const {
  const PointState& s = state[i];
  PointRecord p;
  p.position_m = position_m[i];
  p.normal = normal(i);
  p.information[0] = s.info_xx; p.information[1] = s.info_xy; p.information[2] = s.info_xz;
  p.information[3] = s.info_yy; p.information[4] = s.info_yz; p.information[5] = s.info_zz;
  p.rgb[0] = s.r; p.rgb[1] = s.g; p.rgb[2] = s.b;
  p.merges = s.merges;
  p.violations = s.violations;
  p.last_frame = s.last_frame;
  return p;
}

void PointArrays::set(size_t i, const PointRecord& p) {
  position_m[i] = p.position_m;
  state[i] = state_of(p);
}

void PointArrays::append(const PointArrays& o) {
  // As push_back(): no more room than the points need and an eighth.
  if (size() + o.size() > position_m.capacity()) reserve(size() + o.size() + size() / 8 + 16);
  position_m.insert(position_m.end(), o.position_m.begin(), o.position_m.end());
  state.insert(state.end(), o.state.begin(), o.state.end());
}

size_t PointArrays::compact(const std::vector<uint8_t>& keep) {
  const size_t n = size();
  size_t out = 0;
  for (size_t i = 0; i < n; ++i) {
    if (!keep[i]) continue;
    if (out != i) {
      position_m[out] = position_m[i];
      state[out] = state[i];
    }
    ++out;
  }
  position_m.resize(out);
  state.resize(out);
  return n - out;
}

size_t PointArrays::memory_bytes() const {
  return position_m.capacity() * sizeof(Eigen::Vector3f) + state.capacity() * sizeof(PointState);
}

bool PointArrays::operator==(const PointArrays& o) const {
  return size() == o.size() && o.state.size() == state.size() &&
         (empty() || (std::memcmp(position_m.data(), o.position_m.data(),
                                  size() * sizeof(Eigen::Vector3f)) == 0 &&
                      std::memcmp(state.data(), o.state.data(), size() * sizeof(PointState)) == 0));
}

float uncertainty_m(const PointArrays& a, size_t i) {
  // No inverse is formed, which makes this a quarter of the cost of one (the map preview calls it
  // for every point of the chunks it sends).
  float cofactors, det;
  covariance_trace_parts(a.state[i], &cofactors, &det);
  if (!(det > 0.0f)) return std::numeric_limits<float>::infinity();
  return std::sqrt(std::max(0.0f, cofactors / (3.0f * det)));
}

}  // namespace depthfuse
