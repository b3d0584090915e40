// The decoder's per-row kernels: plain loops over structure-of-arrays rows (one float array per
// quantity), no branches the compiler cannot turn into selects, so that they vectorise. The logic
// that orders them over a frame is in depth_decoder.cpp.
#pragma once

#include <cstddef>
#include <cstdint>

#include "depthfuse/kinect2/raw_depth.hpp"

namespace depthfuse::kinect2::kernels {

// The firmware's constants as DecodeConstants names them, and what the kernels derive from them
// and from the decoder's options.
struct KernelConstants {
  DecodeConstants firmware;
  float bilateral_threshold;  // joint_bilateral_ab_threshold^2 / ab_multiplier^2
  float min_depth_mm;
  float max_depth_mm;
};
KernelConstants make_kernel_constants(const DecodeConstants& c, float min_depth_m,
                                      float max_depth_m);

// One row of one sub-image (kRawRowBytes) to its 512 correlation values in pixel order. Columns 0
// and 511 read as code 0, as the firmware's decoder has them. Reads up to 5 bytes past the row:
// never pass the packet's last row.
void unpack_row(const uint8_t* row_bytes, const float* code_value, float* values);

// One frequency of one row: the three correlation values m0..m2 to the phasor (a, b) with the
// per-pixel cos and sin of P0 and the phase steps' cos and sin (the sum over k of m_k times cos
// and -sin of (P0 + step k)); its unit vector (0 where the phasor is 0) and amplitude. Pixels
// with z <= 0 (outside the lens) give 0; saturated ones give a phasor of 0 and amplitude 65535.
struct PhasorRow {
  float* a;
  float* b;
  float* unit_a;
  float* unit_b;
  float* amplitude;
};
struct PhaseSteps {
  float cos[3];
  float sin[3];
};
void correlate_row(const float* m0, const float* m1, const float* m2, const float* cos_p0,
                   const float* sin_p0, const float* z, const PhaseSteps& steps,
                   float multiplier, float ab_multiplier, const PhasorRow& out);

// IR amplitude of a row: the mean of the three frequencies' amplitudes, scaled, at most 65535.
void ir_row(const float* amplitude0, const float* amplitude1, const float* amplitude2,
            float ab_output_multiplier, float* ir);

// The joint bilateral filter weighs each neighbour by how far its phasor's direction is from the
// centre's: distance (1 - cos of the angle between them) / 2 and weight exp(-c distance). Both
// are the same for either pixel of a pair, so they are computed once per pair of neighbouring
// pixels: pair_weights does `count` pairs (unit_a[i], unit_b[i]) - (other_unit_a[i],
// other_unit_b[i]).
void pair_weights(const float* unit_a, const float* unit_b, const float* other_unit_a,
                  const float* other_unit_b, int count, const KernelConstants& k,
                  float* distance, float* weight);

// The pairs of each pixel x of a row with its eight neighbours, in raster order (up-left, up,
// up-right, left, right, down-left, down, down-right): distance[n][x] and weight[n][x].
struct NeighbourPairs {
  const float* distance[8];
  const float* weight[8];
};

// The joint bilateral filter of one frequency over columns 1..510 of an inner row: `above`,
// `here` and `below` are the phasor rows y-1, y, y+1. Writes the filtered phasor and ANDs the
// "no edge" test into `edge_ok` (1 or 0).
struct PhasorRows {
  const float* a;
  const float* b;
};
void bilateral_row(const PhasorRows& above, const PhasorRows& here, const PhasorRows& below,
                   const NeighbourPairs& pairs, const KernelConstants& k, float* filtered_a,
                   float* filtered_b, float* edge_ok);

// Phase unwrapping of the three frequencies' phasors and the phase-to-depth mapping of one row:
// raw depth in mm (0: no measurement) and the sum of the three amplitudes.
struct UnwrapInput {
  const float* a[3];
  const float* b[3];
  const float* z;       // z table
  const float* x;       // x table
};
// `edge_ok` is the bilateral filter's test (all 1 without it); `edge_depth_mm` is the depth where
// it passed, else 0.
void unwrap_row(const UnwrapInput& in, const float* edge_ok, const KernelConstants& k,
                float* depth_mm, float* edge_depth_mm, float* ir_sum);

// The edge-aware filter of an inner row, from the rows y-1, y, y+1 of raw depth, depth where the
// bilateral filter's edge test passed (else 0) and amplitude sums; writes depth in the output's
// unit (`per_mm` of it a millimetre: 0.001 for metres, 1 for millimetres), 0 out of
// [min_depth_mm, max_depth_mm]. Columns 0 and 511 are only range checked.
struct EdgeRows {
  const float* depth_mm;
  const float* edge_depth_mm;
  const float* ir_sum;
};
void edge_filter_row(const EdgeRows& above, const EdgeRows& here, const EdgeRows& below,
                     const KernelConstants& k, float per_mm, float* depth_out);

// Depth of a row in the output's unit without the neighbourhood test: in range or 0
// (`range_check`), else as is.
void depth_row(const float* depth_mm, bool range_check, const KernelConstants& k, float per_mm,
               float* depth_out);

}  // namespace depthfuse::kinect2::kernels
