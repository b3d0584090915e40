#include "depthfuse/point_arrays.hpp"

#include <cmath>
#include <limits>

#include <Eigen/LU>

namespace depthfuse {

// Applies fn to every column of the structure-of-arrays, so that adding a field means touching one
// list instead of every method.
template <typename A, typename Fn>
static void for_each_column(A& a, Fn&& fn) {
  fn(a.x); fn(a.y); fn(a.z);
  fn(a.nx); fn(a.ny); fn(a.nz);
  fn(a.info_xx); fn(a.info_xy); fn(a.info_xz); fn(a.info_yy); fn(a.info_yz); fn(a.info_zz);
  fn(a.r); fn(a.g); fn(a.b);
  fn(a.merges); fn(a.violations);
  fn(a.last_frame);
}

void PointArrays::reserve(size_t n) {
  for_each_column(*this, [n](auto& v) { v.reserve(n); });
}

void PointArrays::clear() {
  for_each_column(*this, [](auto& v) { v.clear(); });
}

void PointArrays::push_back(const PointRecord& p) {
  x.push_back(p.position_m.x()); y.push_back(p.position_m.y()); z.push_back(p.position_m.z());
  nx.push_back(p.normal.x()); ny.push_back(p.normal.y()); nz.push_back(p.normal.z());
  info_xx.push_back(p.information[0]); info_xy.push_back(p.information[1]);
  info_xz.push_back(p.information[2]); info_yy.push_back(p.information[3]);
  info_yz.push_back(p.information[4]); info_zz.push_back(p.information[5]);
  r.push_back(p.rgb[0]); g.push_back(p.rgb[1]); b.push_back(p.rgb[2]);
  merges.push_back(p.merges); violations.push_back(p.violations);
  last_frame.push_back(p.last_frame);
}

PointRecord PointArrays::get(size_t i) const {
  PointRecord p;
  p.position_m = position(i);
  p.normal = normal(i);
  p.information[0] = info_xx[i]; p.information[1] = info_xy[i]; p.information[2] = info_xz[i];
  p.information[3] = info_yy[i]; p.information[4] = info_yz[i]; p.information[5] = info_zz[i];
  p.rgb[0] = r[i]; p.rgb[1] = g[i]; p.rgb[2] = b[i];
  p.merges = merges[i];
  p.violations = violations[i];
  p.last_frame = last_frame[i];
  return p;
}

void PointArrays::set(size_t i, const PointRecord& p) {
  x[i] = p.position_m.x(); y[i] = p.position_m.y(); z[i] = p.position_m.z();
  nx[i] = p.normal.x(); ny[i] = p.normal.y(); nz[i] = p.normal.z();
  info_xx[i] = p.information[0]; info_xy[i] = p.information[1]; info_xz[i] = p.information[2];
  info_yy[i] = p.information[3]; info_yz[i] = p.information[4]; info_zz[i] = p.information[5];
  r[i] = p.rgb[0]; g[i] = p.rgb[1]; b[i] = p.rgb[2];
  merges[i] = p.merges;
  violations[i] = p.violations;
  last_frame[i] = p.last_frame;
}

void PointArrays::append(const PointArrays& o) {
  // Pair up columns of *this and o by walking both with the same visitor order.
  std::vector<void*> dst;
  for_each_column(*this, [&dst](auto& v) { dst.push_back(&v); });
  size_t k = 0;
  for_each_column(o, [&dst, &k](const auto& v) {
    auto* d = static_cast<std::remove_const_t<std::remove_reference_t<decltype(v)>>*>(dst[k++]);
    d->insert(d->end(), v.begin(), v.end());
  });
}

size_t PointArrays::compact(const std::vector<uint8_t>& keep) {
  const size_t n = size();
  size_t out = 0;
  for (size_t i = 0; i < n; ++i) {
    if (!keep[i]) continue;
    if (out != i) {
      for_each_column(*this, [i, out](auto& v) { v[out] = v[i]; });
    }
    ++out;
  }
  for_each_column(*this, [out](auto& v) { v.resize(out); });
  return n - out;
}

size_t PointArrays::memory_bytes() const {
  size_t bytes = 0;
  for_each_column(*this, [&bytes](const auto& v) { bytes += v.capacity() * sizeof(v[0]); });
  return bytes;
}

bool PointArrays::operator==(const PointArrays& o) const {
  std::vector<const void*> mine;
  for_each_column(*this, [&mine](const auto& v) { mine.push_back(&v); });
  size_t k = 0;
  bool equal = true;
  for_each_column(o, [&](const auto& v) {
    const auto* m = static_cast<const std::remove_reference_t<decltype(v)>*>(mine[k++]);
    equal = equal && (*m == v);
  });
  return equal;
}

float uncertainty_m(const PointArrays& a, size_t i) {
  const Eigen::Matrix3f info = information_matrix(a, i);
  if (info.determinant() <= 0.0f) return std::numeric_limits<float>::infinity();
  const Eigen::Matrix3f cov = info.inverse();
  return std::sqrt(std::max(0.0f, cov.trace() / 3.0f));
}

}  // namespace depthfuse
