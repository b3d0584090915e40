#include "decode_kernels.hpp"

#include <cmath>
#include <cstring>

#include "fast_math.hpp"

// The loops are also compiled for AVX2 and AVX-512 and the loader picks what the CPU runs, as the
// core's per-frame loops do (DEPTHFUSE_VECTOR_CLONES). AVX-512 too because these loops are most of
// a packet's time and twice as wide pays for them (the core's loops gain less).
#if !defined(DF_NO_VECTOR_CLONES) && defined(__GNUC__) && !defined(__clang__) && \
    defined(__x86_64__) && defined(__ELF__)
#define DF_K2_CLONES __attribute__((target_clones("default", "avx2", "avx512f")))
#else
#define DF_K2_CLONES
#endif

namespace depthfuse::kinect2::kernels {

namespace {

constexpr int kW = kRawWidth;

// floor for |v| < 2^31, as a vectorisable truncation (std::floor is a libm call before SSE4.1).
inline float floor_small(float v) {
  const float t = static_cast<float>(static_cast<int32_t>(v));
  return t > v ? t - 1.0f : t;
}

}  // namespace

KernelConstants make_kernel_constants(const DecodeConstants& c, float min_depth_m,
                                      float max_depth_m) {
  KernelConstants k{};
  k.firmware = c;
  k.bilateral_threshold = (c.joint_bilateral_ab_threshold * c.joint_bilateral_ab_threshold) /
                          (c.ab_multiplier * c.ab_multiplier);
  k.min_depth_mm = min_depth_m * 1000.0f;
  k.max_depth_mm = max_depth_m * 1000.0f;
  return k;
}

void unpack_row(const uint8_t* row_bytes, const float* code_value, float* values) {
  // Stream position p holds pixel x = 4 * (p % 128) + p / 128, its code at bit 11 p. Eight codes
  // fill 11 bytes; each group of eight is read as two 8-byte little-endian words (the 5 bytes
  // past a row's end are the next row's or the next sub-image's: unpack_row is never given the
  // last row of the packet).
  for (int group = 0; group < kW / 8; ++group) {
    uint64_t low, high;  // bits 0..63 and 64..127 of the group (little-endian)
    std::memcpy(&low, row_bytes + 11 * group, 8);
    std::memcpy(&high, row_bytes + 11 * group + 8, 8);
    const int p0 = 8 * group;
    float* out = values + 4 * (p0 & 127) + (p0 >> 7);
    out[0] = code_value[low & 2047];
    out[4] = code_value[(low >> 11) & 2047];
    out[8] = code_value[(low >> 22) & 2047];
    out[12] = code_value[(low >> 33) & 2047];
    out[16] = code_value[(low >> 44) & 2047];
    out[20] = code_value[((low >> 55) | (high << 9)) & 2047];
    out[24] = code_value[(high >> 2) & 2047];
    out[28] = code_value[(high >> 13) & 2047];
  }
  // Positions 0 and 511 (x = 0 and x = 511) are not read by the firmware's decoder.
  values[0] = code_value[0];
  values[kW - 1] = code_value[0];
}

DF_K2_CLONES
void correlate_row(const float* __restrict m0, const float* __restrict m1,
                   const float* __restrict m2, const float* __restrict cos_p0,
                   const float* __restrict sin_p0, const float* __restrict z,
                   const PhaseSteps& steps, float multiplier, float ab_multiplier,
                   const PhasorRow& out) {
  float* __restrict a_out = out.a;
  float* __restrict b_out = out.b;
  float* __restrict ua_out = out.unit_a;
  float* __restrict ub_out = out.unit_b;
  float* __restrict amplitude_out = out.amplitude;
  const float c0 = steps.cos[0], c1 = steps.cos[1], c2 = steps.cos[2];
  const float s0 = steps.sin[0], s1 = steps.sin[1], s2 = steps.sin[2];
  for (int x = 0; x < kW; ++x) {
    const bool inside = 0.0f < z[x];
    const bool saturated =
        (m0[x] == kRawSaturated) | (m1[x] == kRawSaturated) | (m2[x] == kRawSaturated);
    // Patent US 8,587,771 B2: the phasor of the three phase-stepped correlations, the sums over
    // k of m_k cos(P0 + step k) and -m_k sin(P0 + step k).
    const float in_phase = m0[x] * c0 + m1[x] * c1 + m2[x] * c2;
    const float quadrature = m0[x] * s0 + m1[x] * s1 + m2[x] * s2;
    const float a = (cos_p0[x] * in_phase - sin_p0[x] * quadrature) * multiplier;
    const float b = (-sin_p0[x] * in_phase - cos_p0[x] * quadrature) * multiplier;
    const float amplitude = std::sqrt(a * a + b * b) * ab_multiplier;
    const bool measured = inside & !saturated;
    const float a_kept = measured ? a : 0.0f;
    const float b_kept = measured ? b : 0.0f;
    a_out[x] = a_kept;
    b_out[x] = b_kept;
    amplitude_out[x] = inside ? (saturated ? 65535.0f : amplitude) : 0.0f;
    const float norm2 = a_kept * a_kept + b_kept * b_kept;
    const float inverse_norm = 1.0f / std::sqrt(norm2 > 0.0f ? norm2 : 1.0f);
    ua_out[x] = norm2 > 0.0f ? a_kept * inverse_norm : 0.0f;
    ub_out[x] = norm2 > 0.0f ? b_kept * inverse_norm : 0.0f;
  }
}

DF_K2_CLONES
void ir_row(const float* __restrict amplitude0, const float* __restrict amplitude1,
            const float* __restrict amplitude2, float ab_output_multiplier, float* __restrict ir) {
  for (int x = 0; x < kW; ++x)
    ir[x] = std::min((amplitude0[x] + amplitude1[x] + amplitude2[x]) * 0.3333333f *
                         ab_output_multiplier,
                     65535.0f);
}

DF_K2_CLONES
void pair_weights(const float* __restrict unit_a, const float* __restrict unit_b,
                  const float* __restrict other_unit_a, const float* __restrict other_unit_b,
                  int count, const KernelConstants& k, float* __restrict distance,
                  float* __restrict weight) {
  const float exp_factor = -1.442695f * k.firmware.joint_bilateral_exp;
  for (int i = 0; i < count; ++i) {
    // The firmware's expression, symmetric in the two pixels to the last bit.
    float d = -(other_unit_a[i] * unit_a[i] + other_unit_b[i] * unit_b[i]);
    d += 1.0f;
    d *= 0.5f;
    distance[i] = d;
    weight[i] = fast::exp_weight(exp_factor * d);
  }
}

namespace {

struct NeighbourSums {
  float weight, a, b, distance;
  bool zero_seen;
};

// One neighbour (phasor qa, qb) of the bilateral filter at the given distance from the centre,
// with the weight of that distance for a strong centre (a weak one weighs all alike).
inline void add_neighbour(float g, float qa, float qb, float distance, float similarity,
                          bool weak, float neighbour_threshold, NeighbourSums& sums) {
  const float q_norm2 = qa * qa + qb * qb;
  sums.zero_seen = sums.zero_seen | (q_norm2 == 0.0f);
  const bool used = q_norm2 >= neighbour_threshold;
  const float weight = used ? (weak ? g : g * similarity) : 0.0f;
  sums.distance += used ? distance : 0.0f;
  sums.a += weight * qa;
  sums.b += weight * qb;
  sums.weight += weight;
}

}  // namespace

DF_K2_CLONES
void bilateral_row(const PhasorRows& above, const PhasorRows& here, const PhasorRows& below,
                   const NeighbourPairs& pairs, const KernelConstants& k,
                   float* __restrict filtered_a, float* __restrict filtered_b,
                   float* __restrict edge_ok) {
  // Rows y-1 (0), y (1), y+1 (2).
  const float* __restrict a0 = above.a;
  const float* __restrict b0 = above.b;
  const float* __restrict a1 = here.a;
  const float* __restrict b1 = here.b;
  const float* __restrict a2 = below.a;
  const float* __restrict b2 = below.b;
  const float* __restrict d_ul = pairs.distance[0];
  const float* __restrict d_u = pairs.distance[1];
  const float* __restrict d_ur = pairs.distance[2];
  const float* __restrict d_l = pairs.distance[3];
  const float* __restrict d_r = pairs.distance[4];
  const float* __restrict d_dl = pairs.distance[5];
  const float* __restrict d_d = pairs.distance[6];
  const float* __restrict d_dr = pairs.distance[7];
  const float* __restrict w_ul = pairs.weight[0];
  const float* __restrict w_u = pairs.weight[1];
  const float* __restrict w_ur = pairs.weight[2];
  const float* __restrict w_l = pairs.weight[3];
  const float* __restrict w_r = pairs.weight[4];
  const float* __restrict w_dl = pairs.weight[5];
  const float* __restrict w_d = pairs.weight[6];
  const float* __restrict w_dr = pairs.weight[7];
  // Constants in locals: a load under a condition would keep the loop from vectorising.
  const float threshold = k.bilateral_threshold;
  const float max_edge = k.firmware.joint_bilateral_max_edge;
  float g[9];
  for (int j = 0; j < 9; ++j) g[j] = k.firmware.gaussian_kernel[j];
  for (int x = 1; x < kW - 1; ++x) {
    const float ca = a1[x];
    const float cb = b1[x];
    const float norm2 = ca * ca + cb * cb;
    // A weak centre is averaged with all its neighbours alike.
    const bool weak = norm2 < threshold;
    const float t = weak ? 0.0f : threshold;
    NeighbourSums sums{0.0f, 0.0f, 0.0f, 0.0f, norm2 == 0.0f};
    // The firmware's order of summation: row by row, the centre in its place.
    add_neighbour(g[0], a0[x - 1], b0[x - 1], d_ul[x], w_ul[x], weak, t, sums);
    add_neighbour(g[1], a0[x], b0[x], d_u[x], w_u[x], weak, t, sums);
    add_neighbour(g[2], a0[x + 1], b0[x + 1], d_ur[x], w_ur[x], weak, t, sums);
    add_neighbour(g[3], a1[x - 1], b1[x - 1], d_l[x], w_l[x], weak, t, sums);
    sums.weight += g[4];
    sums.a += g[4] * ca;
    sums.b += g[4] * cb;
    add_neighbour(g[5], a1[x + 1], b1[x + 1], d_r[x], w_r[x], weak, t, sums);
    add_neighbour(g[6], a2[x - 1], b2[x - 1], d_dl[x], w_dl[x], weak, t, sums);
    add_neighbour(g[7], a2[x], b2[x], d_d[x], w_d[x], weak, t, sums);
    add_neighbour(g[8], a2[x + 1], b2[x + 1], d_dr[x], w_dr[x], weak, t, sums);
    // Where the firmware's unit vector of a zero phasor (0 * inf) meets a weak centre, its
    // NaN empties the pixel and fails the edge test.
    const bool poisoned = weak & sums.zero_seen;
    filtered_a[x] = poisoned ? 0.0f : sums.a / sums.weight;
    filtered_b[x] = poisoned ? 0.0f : sums.b / sums.weight;
    const float edge_ok_before = edge_ok[x];
    edge_ok[x] = (poisoned | !(sums.distance < max_edge)) ? 0.0f : edge_ok_before;
  }
}

// Long on purpose: a hot kernel whose loops share stack rows, vectorised whole in every ISA clone.
DF_K2_CLONES
void unwrap_row(const UnwrapInput& in, const float* __restrict edge_ok, const KernelConstants& k,
                float* __restrict depth_mm, float* __restrict edge_depth_mm,
                float* __restrict ir_sum) {
  const float* __restrict z_table = in.z;
  const float* __restrict x_table = in.x;
  constexpr float kTwoPi = 6.28318548f;
  const float ab_multiplier = k.firmware.ab_multiplier;
  const float slope = k.firmware.ab_confidence_slope;
  const bool slope_positive = 0.0f < slope;
  const float confidence_offset = k.firmware.ab_confidence_offset;
  const float min_confidence = k.firmware.min_dealias_confidence;
  const float max_confidence = k.firmware.max_dealias_confidence;
  const float individual_threshold = k.firmware.individual_ab_threshold;
  const float sum_threshold = k.firmware.ab_threshold;
  const float phase_offset = k.firmware.phase_offset;
  const float unambiguous_mm = k.firmware.unambiguous_distance_mm;
  // The three phases in units of their own wavelength: the frequencies wrap 3, 15 and 2 times
  // over the unambiguous range. (Loops of their own: one loop for everything is more than GCC
  // turns into straight-line vector code.)
  alignas(32) float t[3][kW];
  alignas(32) float amplitude[3][kW];
  const float wraps[3] = {3.0f, 15.0f, 2.0f};
  for (int f = 0; f < 3; ++f) {
    const float* __restrict a = in.a[f];
    const float* __restrict b = in.b[f];
    float* __restrict tf = t[f];
    float* __restrict amplitude_f = amplitude[f];
    const float wrap_per_radian = wraps[f] / kTwoPi;
    for (int x = 0; x < kW; ++x) {
      float phase = fast::atan2(b[x], a[x]);
      phase = phase < 0.0f ? phase + kTwoPi : phase;
      tf[x] = phase * wrap_per_radian;
      amplitude_f[x] = std::sqrt(a[x] * a[x] + b[x] * b[x]) * ab_multiplier;
    }
  }
  alignas(32) float unwrapped[kW];
  alignas(32) float disagreement[kW];
  for (int x = 0; x < kW; ++x) {
    // Unwrap 0 against 1, then both against 2.
    const float t0 = t[0][x], t1 = t[1][x], t2 = t[2][x];
    const float t5 = floor_small((t1 - t0) * 0.333333f + 0.5f) * 3.0f + t0;
    float t3 = -t2 + t5;
    const float t4 = t3 * 2.0f;
    // +-0.5 and then +-2 by the sign of t4 (as one select: two keep GCC from vectorising for AVX2).
    const float half = t4 >= -t4 ? 0.5f : -0.5f;
    t3 *= half;
    t3 = (t3 - floor_small(t3)) * (half * 4.0f);
    const bool shifted = (0.5f < std::abs(t3)) & (std::abs(t3) < 1.5f);
    float t6 = shifted ? t5 + 15.0f : t5;
    float t7 = shifted ? t1 + 15.0f : t1;
    float t8 = (floor_small((-t2 + t6) * 0.5f + 0.5f) * 2.0f + t2) * 0.5f;
    t6 *= 0.333333f;
    t7 *= 0.066667f;
    const float t9 = t8 + t6 + t7;
    const float t10 = t9 * 0.333333f;
    t6 *= kTwoPi;
    t7 *= kTwoPi;
    t8 *= kTwoPi;
    // How far the three unwrapped phases disagree.
    const float d8 = t7 * 0.826977f - t8 * 0.110264f;
    const float d6 = t8 * 0.551318f - t6 * 0.826977f;
    const float d7 = t6 * 0.110264f - t7 * 0.551318f;
    disagreement[x] = d8 * d8 + d6 * d6 + d7 * d7;
    unwrapped[x] = t9 >= 0.0f ? t10 : 0.0f;
  }
  for (int x = 0; x < kW; ++x) {
    const float amplitude0 = amplitude[0][x], amplitude1 = amplitude[1][x];
    const float amplitude2 = amplitude[2][x];
    const float amplitude_sum = amplitude0 + amplitude1 + amplitude2;
    const float amplitude_min = std::min(std::min(amplitude0, amplitude1), amplitude2);
    const float amplitude_max = std::max(std::max(amplitude0, amplitude1), amplitude2);
    // The disagreement a phasor of this amplitude may have.
    float confidence = fast::log(slope_positive ? amplitude_min : amplitude_max);
    confidence = (confidence * slope * 0.301030f + confidence_offset) *
                 3.321928f;
    confidence = fast::exp(confidence);
    confidence = std::min(max_confidence, std::max(min_confidence, confidence));
    confidence *= confidence;
    const float trusted = confidence >= disagreement[x] ? unwrapped[x] : 0.0f;
    const bool weak =
        (amplitude_min < individual_threshold) | (amplitude_sum < sum_threshold);
    float phase = weak ? 0.0f : trusted;
    phase = 0.0f < phase ? phase + phase_offset : phase;

    // Phase to depth, with the correction for the light source beside the lens.
    const float z = z_table[x];
    const float x_scaled = x_table[x];
    const float ok = edge_ok[x];
    const float depth_linear = z * phase;
    const float travel = phase * unambiguous_mm * 2.0f;
    const bool corrected = (0.0f < depth_linear) & (0.0f < travel);
    const float x_factor = (x_scaled * 90.0f) / (travel * travel * 8192.0f);
    float depth_fit = depth_linear / (-depth_linear * x_factor + 1.0f);
    depth_fit = depth_fit < 0.0f ? 0.0f : depth_fit;
    const float depth = corrected ? depth_fit : depth_linear;
    depth_mm[x] = depth;
    edge_depth_mm[x] = ok == 1.0f ? depth : 0.0f;
    ir_sum[x] = amplitude_sum;
  }
}

namespace {

// Depth in the output's unit, `per_mm` of it a millimetre (1 for millimetres: unchanged).
inline float to_output(float depth_mm, float per_mm) {
  return ((depth_mm > 0.0f) & (depth_mm < 3.0e38f)) ? depth_mm * per_mm : 0.0f;
}

inline bool in_range(float depth_mm, float min_mm, float max_mm) {
  return (depth_mm >= min_mm) & (depth_mm <= max_mm);
}

}  // namespace

DF_K2_CLONES
void edge_filter_row(const EdgeRows& above, const EdgeRows& here, const EdgeRows& below,
                     const KernelConstants& k, float per_mm, float* __restrict depth_out) {
  const float* __restrict sum_rows[3] = {above.ir_sum, here.ir_sum, below.ir_sum};
  const float* __restrict edge_rows[3] = {above.edge_depth_mm, here.edge_depth_mm,
                                          below.edge_depth_mm};
  const float min_mm = k.min_depth_mm, max_mm = k.max_depth_mm;
  const float spread_threshold = k.firmware.edge_ab_std_dev_threshold;
  const float mean_min = k.firmware.edge_ab_avg_min_value;
  const float close_threshold = k.firmware.edge_close_delta_threshold_mm;
  const float far_threshold = k.firmware.edge_far_delta_threshold_mm;
  const float max_threshold = k.firmware.edge_max_delta_threshold_mm;
  const float mean_threshold = k.firmware.edge_avg_delta_threshold_mm;
  for (int x = 1; x < kW - 1; ++x) {
    const float raw = here.depth_mm[x];
    const float edge_depth = here.edge_depth_mm[x];
    float sum = here.ir_sum[x];
    float square_sum = sum * sum;
    float nearest = raw, farthest = raw;
    auto neighbour = [&](int dy, int dx) {
      const float s = sum_rows[dy][x + dx - 1];
      sum += s;
      square_sum += s * s;
      const float d = edge_rows[dy][x + dx - 1];
      nearest = ((0.0f < d) & (d < nearest)) ? d : nearest;
      farthest = ((0.0f < d) & (farthest < d)) ? d : farthest;
    };
    neighbour(0, 0);
    neighbour(0, 1);
    neighbour(0, 2);
    neighbour(1, 0);
    neighbour(1, 2);
    neighbour(2, 0);
    neighbour(2, 1);
    neighbour(2, 2);
    // Relative spread of the amplitude around the pixel, and how far its depth is from the
    // nearest and farthest neighbour: a flying pixel between a near and a far surface.
    float spread = std::sqrt(square_sum * 9.0f - sum * sum) / 9.0f;
    spread /= std::max(sum / 9.0f, mean_min);
    const float to_nearest = std::abs(raw - nearest);
    const float to_farthest = std::abs(raw - farthest);
    const float mean_difference = (to_nearest + to_farthest) * 0.5f;
    const float max_difference = std::max(to_nearest, to_farthest);
    const bool flying = (0.0f < raw) & (spread >= spread_threshold) &
                        (close_threshold < to_nearest) & (far_threshold < to_farthest) &
                        (max_threshold < max_difference) & (mean_threshold < mean_difference);
    const float kept = flying ? 0.0f : edge_depth;
    depth_out[x] = in_range(raw, min_mm, max_mm) ? to_output(kept, per_mm) : 0.0f;
  }
  for (int x : {0, kW - 1}) {
    const float d = here.depth_mm[x];
    depth_out[x] = in_range(d, min_mm, max_mm) ? to_output(d, per_mm) : 0.0f;
  }
}

DF_K2_CLONES
void depth_row(const float* __restrict depth_mm, bool range_check, const KernelConstants& k,
               float per_mm, float* __restrict depth_out) {
  const float min_mm = k.min_depth_mm, max_mm = k.max_depth_mm;
  for (int x = 0; x < kW; ++x) {
    const float d = depth_mm[x];
    const bool kept = !range_check | in_range(d, min_mm, max_mm);
    depth_out[x] = kept ? to_output(d, per_mm) : 0.0f;
  }
}

}  // namespace depthfuse::kinect2::kernels
