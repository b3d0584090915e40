// Branch-free float approximations of exp, log and atan2 that the compiler can vectorise (the
// libm calls cannot be, and would cost more than the rest of the decoder together). Accurate to a
// few units in the last place over the ranges the decoder uses; exp(0) is exactly 1.
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstring>

namespace depthfuse::kinect2::fast {

inline float bits_to_float(int32_t bits) {
  float f;
  std::memcpy(&f, &bits, sizeof f);
  return f;
}

inline int32_t float_to_bits(float f) {
  int32_t bits;
  std::memcpy(&bits, &f, sizeof bits);
  return bits;
}

// e^x for x within [-87, 88] (no clamping), by 2^n e^r with |r| <= ln(2)/2 and the Taylor
// polynomial of e^r to r^Degree: relative error < 1e-7 for 7, < 4e-6 for 5. exp(0) is exactly 1.
template <int Degree>
inline float exp_in_range(float x) {
  // n = round(x / ln 2) by the 1.5 * 2^23 trick (exact under round-to-nearest).
  const float n = (x * 1.44269504f + 12582912.0f) - 12582912.0f;
  float r = x - n * 0.693145752f;  // ln 2 split in two so that n * ln2_hi is exact
  r = r - n * 1.42860677e-6f;
  float inverse_factorial = 1.0f;
  for (int i = 2; i <= Degree; ++i) inverse_factorial /= static_cast<float>(i);
  float p = inverse_factorial;  // Horner, from 1/Degree! down to 1/0!
  for (int i = Degree; i > 0; --i) {
    inverse_factorial *= static_cast<float>(i);
    p = p * r + inverse_factorial;
  }
  return p * bits_to_float((static_cast<int32_t>(n) + 127) << 23);
}

// e^x, clamped to [-87, 88].
inline float exp(float x) { return exp_in_range<7>(std::min(std::max(x, -87.0f), 88.0f)); }

// e^x for the bilateral filter's weights, x in [-10, 0]: 5 terms are far below what moves a
// filtered phase by a micrometre of depth.
inline float exp_weight(float x) { return exp_in_range<5>(x); }

// ln x for finite x > 0 (normal numbers).
inline float log(float x) {
  const int32_t bits = float_to_bits(x);
  float exponent = static_cast<float>(((bits >> 23) & 255) - 127);
  float m = bits_to_float((bits & 0x7fffff) | 0x3f800000);  // [1, 2)
  const bool high = m > 1.41421356f;
  m = high ? m * 0.5f : m;
  exponent = high ? exponent + 1.0f : exponent;
  // ln m = 2 atanh(s), s = (m - 1) / (m + 1), |s| <= 0.172.
  const float s = (m - 1.0f) / (m + 1.0f);
  const float s2 = s * s;
  float p = 1.0f / 11.0f;
  p = p * s2 + 1.0f / 9.0f;
  p = p * s2 + 1.0f / 7.0f;
  p = p * s2 + 1.0f / 5.0f;
  p = p * s2 + 1.0f / 3.0f;
  p = p * s2 + 1.0f;
  return exponent * 0.693147181f + 2.0f * s * p;
}

// atan2(y, x) in [-pi, pi]; atan2(0, 0) = 0.
inline float atan2(float y, float x) {
  const float ax = std::abs(x);
  const float ay = std::abs(y);
  const float larger = std::max(ax, ay);
  const float smaller = std::min(ax, ay);
  // atan a = pi/4 + atan((a - 1) / (a + 1)) brings a = smaller / larger within tan(pi/8); as
  // (smaller - larger) / (smaller + larger), one division either way.
  const bool reduce = smaller > 0.414213562f * larger;
  const float numerator = reduce ? smaller - larger : smaller;
  const float denominator = reduce ? smaller + larger : (larger > 0.0f ? larger : 1.0f);
  const float r = numerator / denominator;
  const float r2 = r * r;
  float p = 1.0f / 13.0f;
  p = p * r2 - 1.0f / 11.0f;
  p = p * r2 + 1.0f / 9.0f;
  p = p * r2 - 1.0f / 7.0f;
  p = p * r2 + 1.0f / 5.0f;
  p = p * r2 - 1.0f / 3.0f;
  p = p * r2 + 1.0f;
  float angle = (reduce ? 0.785398163f : 0.0f) + r * p;
  angle = ay > ax ? 1.57079633f - angle : angle;
  angle = x < 0.0f ? 3.14159265f - angle : angle;
  return y < 0.0f ? -angle : angle;
}

}  // namespace depthfuse::kinect2::fast
