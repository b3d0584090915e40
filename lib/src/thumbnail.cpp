#include "thumbnail.hpp"

#include <cmath>

namespace depthfuse {

Thumbnail make_thumbnail(const MeasurementImage& m) {
  std::array<float, kThumbW * kThumbH> sum{};
  std::array<int, kThumbW * kThumbH> count{};
  constexpr int kStep = 4;  // every 4th pixel in u and v is plenty for a 16 x 12 average
  for (int v = 0; v < m.height; v += kStep) {
    const int tv = v * kThumbH / m.height;
    for (int u = 0; u < m.width; u += kStep) {
      const size_t i = static_cast<size_t>(v) * m.width + u;
      if (!m.valid[i]) continue;
      const int t = tv * kThumbW + u * kThumbW / m.width;
      sum[t] += m.z[i];
      ++count[t];
    }
  }
  Thumbnail out{};
  for (size_t t = 0; t < out.size(); ++t) out[t] = count[t] ? sum[t] / count[t] : 0.0f;
  return out;
}

double similarity(const Thumbnail& a, const Thumbnail& b) {
  double ma = 0, mb = 0;
  int both = 0, either = 0;
  for (size_t t = 0; t < a.size(); ++t) {
    either += (a[t] > 0) || (b[t] > 0);
    if (a[t] > 0 && b[t] > 0) {
      ma += a[t];
      mb += b[t];
      ++both;
    }
  }
  if (both < 8) return -1.0;
  ma /= both;
  mb /= both;
  double sab = 0, saa = 0, sbb = 0;
  for (size_t t = 0; t < a.size(); ++t) {
    if (!(a[t] > 0 && b[t] > 0)) continue;
    const double da = a[t] - ma, db = b[t] - mb;
    sab += da * db;
    saa += da * da;
    sbb += db * db;
  }
  const double ncc = saa > 0 && sbb > 0 ? sab / std::sqrt(saa * sbb) : 0.0;
  return ncc * both / either;
}

}  // namespace depthfuse
