// Internal: the global descriptor that ranks keyframes, for the relocaliser and the loop closer's
// place search: the frame's depth averaged over a coarse grid (a "small blurry image", as PTAM's
// relocaliser uses). Cheap to compare against every keyframe; it only orders the candidates,
// sample consensus and ICP decide.
#pragma once

#include <array>

#include "depthfuse/measurement.hpp"

namespace depthfuse {

constexpr int kThumbW = 16, kThumbH = 12;
using Thumbnail = std::array<float, kThumbW * kThumbH>;  // mean depth, m; 0: no measurement

Thumbnail make_thumbnail(const MeasurementImage& m);

// Zero-mean normalised cross-correlation of the cells both thumbnails have, times the share of
// cells either has that both have: in [-1, 1], higher is more alike.
double similarity(const Thumbnail& a, const Thumbnail& b);

}  // namespace depthfuse
