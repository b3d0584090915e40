// The 16-bit delta transform (see delta16.hpp). One loop per run, the zigzag decided outside it
// (a template), so that the compiler can vectorise the planes' stores.
#include "depthfuse/base/delta16.hpp"

#include <algorithm>

namespace depthfuse {

namespace {

inline uint16_t zigzag(uint16_t step) {
  const auto s = static_cast<int16_t>(step);
  return static_cast<uint16_t>((static_cast<uint16_t>(s) << 1) ^ static_cast<uint16_t>(s >> 15));
}

inline uint16_t unzigzag(uint16_t z) {
  return static_cast<uint16_t>((z >> 1) ^ static_cast<uint16_t>(-(z & 1)));
}

template <bool kZigzag>
void to_planes(const uint16_t* values, size_t n, size_t run, uint8_t* low, uint8_t* high) {
  for (size_t begin = 0; begin < n; begin += run) {
    const size_t end = std::min(n, begin + run);
    uint16_t prev = 0;
    for (size_t i = begin; i < end; ++i) {
      const uint16_t v = values[i];
      uint16_t e = static_cast<uint16_t>(v - prev);
      if (kZigzag) e = zigzag(e);
      low[i] = static_cast<uint8_t>(e);
      high[i] = static_cast<uint8_t>(e >> 8);
      prev = v;
    }
  }
}

template <bool kZigzag>
void from_planes(const uint8_t* low, const uint8_t* high, size_t n, size_t run, uint16_t* values) {
  for (size_t begin = 0; begin < n; begin += run) {
    const size_t end = std::min(n, begin + run);
    uint16_t prev = 0;
    for (size_t i = begin; i < end; ++i) {
      uint16_t e = static_cast<uint16_t>(low[i] | (high[i] << 8));
      if (kZigzag) e = unzigzag(e);
      prev = static_cast<uint16_t>(prev + e);
      values[i] = prev;
    }
  }
}

}  // namespace

void delta16_to_planes(const uint16_t* values, size_t n, const Delta16Layout& layout,
                       uint8_t* planes) {
  const size_t run = std::max<size_t>(1, layout.run);
  if (layout.zigzag) to_planes<true>(values, n, run, planes, planes + n);
  else to_planes<false>(values, n, run, planes, planes + n);
}

void delta16_from_planes(const uint8_t* planes, size_t n, const Delta16Layout& layout,
                         uint16_t* values) {
  const size_t run = std::max<size_t>(1, layout.run);
  if (layout.zigzag) from_planes<true>(planes, planes + n, n, run, values);
  else from_planes<false>(planes, planes + n, n, run, values);
}

}  // namespace depthfuse
