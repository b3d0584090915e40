// What a Kinect V2 sends for depth, as plain data (no libfreenect2 types): the layout of one raw
// depth packet, the P0 tables the device reports once, its IR camera calibration, and the
// parameters of the decoding. Shared by the decoder (depth_decoder.hpp) and its forward model
// (packet_encoder.hpp).
//
// A packet is 10 sub-images of 512x424 11-bit codes. Sub-images 0-2, 3-5 and 6-8 are the three
// phase-stepped correlation images of the three modulation frequencies; sub-image 9 is not used.
// Each sub-image row is a little-endian bit stream of 512 codes, in the order x = 0, 4, 8, ...,
// then 1, 5, 9, ..., then 2, ..., then 3, ...; the device sends row 212 first, rows 212..423
// then 211..0. A code maps to a signed correlation value through a fixed 2048-entry table (the
// value 32767 means saturated).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "depthfuse/status.hpp"

namespace depthfuse::kinect2 {

constexpr int kRawWidth = 512;
constexpr int kRawHeight = 424;
constexpr size_t kRawPixels = size_t{kRawWidth} * kRawHeight;
constexpr int kRawSubImages = 10;
constexpr size_t kRawRowBytes = kRawWidth * 11 / 8;                 // 704
constexpr size_t kRawSubImageBytes = kRawRowBytes * kRawHeight;     // 298496
constexpr size_t kRawPacketBytes = kRawSubImageBytes * kRawSubImages;  // 2984960
constexpr int16_t kRawSaturated = 32767;

// One depth packet as the device's USB stream parser assembles it.
struct RawDepthPacket {
  uint32_t sequence = 0;   // the device's frame counter
  uint32_t timestamp = 0;  // the device's clock (units of 0.1 ms)
  const uint8_t* bytes = nullptr;
  size_t size = 0;         // must be kRawPacketBytes
};

// The three per-pixel phase offsets ("P0" tables), one per modulation frequency, rows in the order
// the device reports them (the ReadP0Tables command response: bottom row first).
struct P0Tables {
  std::array<std::vector<uint16_t>, 3> table;  // each kRawPixels

  bool empty() const { return table[0].empty(); }
};

// The ReadP0Tables command response: a 32-byte header, then each table framed by two 16-bit words.
constexpr size_t kP0ResponseHeaderBytes = 32;
constexpr size_t kP0ResponseBytes = kP0ResponseHeaderBytes + 3 * (2 + kRawPixels * 2 + 2);
Result<P0Tables> parse_p0_response(const uint8_t* bytes, size_t size);
// kInvalidArgument unless there are three tables of kRawPixels entries.
Status check_p0_tables(const P0Tables& tables);
std::vector<uint8_t> p0_response(const P0Tables& tables);

// The IR camera's factory calibration as the device reports it (libfreenect2's IrCameraParams):
// pinhole in pixels and Brown-Conrady distortion of normalised coordinates.
struct IrCalibration {
  float fx = 0, fy = 0, cx = 0, cy = 0;
  float k1 = 0, k2 = 0, k3 = 0, p1 = 0, p2 = 0;
};
Status check_ir_calibration(const IrCalibration& calibration);
// The undistorted normalised coordinates of the distorted normalised point (xd, yd): the inverse
// of the calibration's distortion, by Newton's method.
void undistort_normalised(const IrCalibration& calibration, double xd, double yd, double* xu,
                          double* yu);

// The constants of the decoding, as the device's firmware has them (libfreenect2's
// DepthPacketProcessor::Parameters); the decoder never needs others, they are named for reading.
struct DecodeConstants {
  float ab_multiplier = 0.6666667f;
  std::array<float, 3> ab_multiplier_per_frequency{1.322581f, 1.0f, 1.612903f};
  float ab_output_multiplier = 16.0f;
  std::array<float, 3> phase_in_rad{0.0f, 2.094395f, 4.18879f};
  float joint_bilateral_ab_threshold = 3.0f;
  float joint_bilateral_max_edge = 2.5f;
  float joint_bilateral_exp = 5.0f;
  std::array<float, 9> gaussian_kernel{0.1069973f, 0.1131098f, 0.1069973f,
                                       0.1131098f, 0.1195716f, 0.1131098f,
                                       0.1069973f, 0.1131098f, 0.1069973f};
  float phase_offset = 0.0f;
  float unambiguous_distance_mm = 2083.333f;
  float individual_ab_threshold = 3.0f;
  float ab_threshold = 10.0f;
  float ab_confidence_slope = -0.5330578f;
  float ab_confidence_offset = 0.7694894f;
  float min_dealias_confidence = 0.3490659f;
  float max_dealias_confidence = 0.6108653f;
  float edge_ab_avg_min_value = 50.0f;
  float edge_ab_std_dev_threshold = 0.05f;
  float edge_close_delta_threshold_mm = 50.0f;
  float edge_far_delta_threshold_mm = 30.0f;
  float edge_max_delta_threshold_mm = 100.0f;
  float edge_avg_delta_threshold_mm = 0.0f;
};

// The fixed table from 11-bit code to correlation value.
const std::array<int16_t, 2048>& code_to_correlation();

}  // namespace depthfuse::kinect2
