// The 16-bit delta transform the wire and the scan file share: lossless for every value and run
// length, both layouts; the planes hold what the two formats document (docs/protocol.md's row
// predictor, docs/checkpoint-format.md's transform 2).
#include <gtest/gtest.h>

#include <random>
#include <vector>

#include "depthfuse/base/delta16.hpp"

namespace depthfuse {
namespace {

std::vector<uint16_t> round_trip(const std::vector<uint16_t>& values, const Delta16Layout& layout) {
  std::vector<uint8_t> planes(2 * values.size());
  delta16_to_planes(values.data(), values.size(), layout, planes.data());
  std::vector<uint16_t> back(values.size(), 0xABCD);
  delta16_from_planes(planes.data(), values.size(), layout, back.data());
  return back;
}

TEST(Delta16, EveryLayoutRoundTripsExtremesAndNoise) {
  std::mt19937 rng(7);
  std::vector<uint16_t> values = {0, 65535, 0, 1, 65534, 32768, 32767, 0};
  for (int i = 0; i < 1000; ++i) values.push_back(static_cast<uint16_t>(rng()));
  for (const size_t run : {size_t{1}, size_t{3}, size_t{7}, size_t{512}, values.size(), size_t{0}})
    for (const bool zigzag : {false, true})
      EXPECT_EQ(round_trip(values, {run, zigzag}), values) << "run " << run << " zigzag " << zigzag;
}

TEST(Delta16, PlanesHoldTheDocumentedSteps) {
  const std::vector<uint16_t> values = {1000, 1002, 999, 7, 9};  // runs of 3: {1000 1002 999} {7 9}
  std::vector<uint8_t> planes(10);
  delta16_to_planes(values.data(), 5, {3, true}, planes.data());
  // Steps 1000, +2, -3 | 7, +2, zigzagged: 2000, 4, 5 | 14, 4; low bytes first, then high bytes.
  EXPECT_EQ(planes, (std::vector<uint8_t>{2000 & 0xff, 4, 5, 14, 4, 2000 >> 8, 0, 0, 0, 0}));
  delta16_to_planes(values.data(), 5, {5, false}, planes.data());
  // Steps 1000, +2, -3 (wrapping: 65533), -992 (64544), +2.
  EXPECT_EQ(planes, (std::vector<uint8_t>{1000 & 0xff, 2, 65533 & 0xff, 64544 & 0xff, 2, 1000 >> 8, 0,
                                          65533 >> 8, 64544 >> 8, 0}));
}

}  // namespace
}  // namespace depthfuse
