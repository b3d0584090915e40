// The per-device tables of the decoder and its forward model, computed once from the P0 tables and
// the IR calibration. All are in packet pixel order: row y of the packet (libfreenect2's output
// row 423 - y), column x.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "depthfuse/kinect2/raw_depth.hpp"

namespace depthfuse::kinect2 {

// Row y of the packet is stored as this row of each sub-image.
inline int packet_storage_row(int y) { return y < kRawHeight / 2 ? y + kRawHeight / 2 : kRawHeight - 1 - y; }

// The P0 value of frequency f at packet pixel (x, y): the device reports the tables upside down.
inline uint16_t p0_at(const P0Tables& p0, int f, int x, int y) {
  return p0.table[f][static_cast<size_t>(kRawHeight - 1 - y) * kRawWidth + x];
}

// The phase offset, in radians, that a P0 value stands for.
float p0_phase_rad(uint16_t p0);

// Per pixel: z_mm_per_phase turns the unwrapped phase into depth along the optical axis
// (the unambiguous distance over the length of the undistorted ray at unit depth), x_scaled is
// 8192 times the undistorted normalised x (the offset of the light source from the lens).
struct RayTables {
  std::vector<float> z_mm_per_phase;
  std::vector<float> x_scaled;
};
RayTables make_ray_tables(const IrCalibration& calibration);

// Per frequency f: cos and sin of the P0 phase offset; and of the three phase steps. The decoder
// needs cos and -sin of (P0 + step k) per pixel: as sums of these products, six tables are read
// per frame instead of eighteen.
struct PhaseTables {
  std::array<std::vector<float>, 3> cos_p0;
  std::array<std::vector<float>, 3> sin_p0;
  std::array<float, 3> cos_step;
  std::array<float, 3> sin_step;

  // cos and -sin of (P0 + step k) of frequency f at pixel i.
  double cos_at(int f, int k, size_t i) const {
    return double{cos_p0[f][i]} * cos_step[k] - double{sin_p0[f][i]} * sin_step[k];
  }
  double neg_sin_at(int f, int k, size_t i) const {
    return -double{sin_p0[f][i]} * cos_step[k] - double{cos_p0[f][i]} * sin_step[k];
  }
};
PhaseTables make_phase_tables(const P0Tables& p0, const DecodeConstants& constants);

}  // namespace depthfuse::kinect2
