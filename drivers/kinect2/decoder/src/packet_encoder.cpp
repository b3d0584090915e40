#include "depthfuse/kinect2/packet_encoder.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <optional>

#include "decoder_tables.hpp"

namespace depthfuse::kinect2 {

namespace {

constexpr int kSaturatedCode = 1024;

// The decoder's final phase is this many times the unwrapped phase in units of the whole range
// over 30 (its averaging constants, 0.9 * 0.333333).
constexpr double kPhasePerUnit = (0.5 + 0.333333 + 0.066667) * 0.333333;

// Nearest 11-bit code of a correlation value (never the saturation code), by an inverse table.
// The correlation values of the codes are integers, so the midpoints between neighbouring ones
// are multiples of 0.5 and the nearest code is the same throughout each half-unit interval
// [h / 2, (h + 1) / 2): one entry per interval gives exactly the nearest code (ties to the
// larger magnitude, as the search it replaces), with one load instead of a binary search.
class CodeBook {
 public:
  CodeBook() {
    const auto& table = code_to_correlation();
    const int largest = table[1023];
    nearest_.resize(2 * static_cast<size_t>(largest) + 1);
    int code = 0;
    for (size_t h = 0; h < nearest_.size(); ++h) {
      const double magnitude = 0.5 * static_cast<double>(h);
      while (code < 1023 && magnitude - table[code] >= table[code + 1] - magnitude) ++code;
      nearest_[h] = static_cast<uint16_t>(code);
    }
    largest_ = static_cast<float>(largest);
  }

  int code_of(float value) const {
    const float magnitude = std::min(std::abs(value), largest_);
    const int code = nearest_[static_cast<size_t>(magnitude * 2.0f)];
    return (value < 0.0f && code > 0) ? 1024 + code : code;
  }

 private:
  std::vector<uint16_t> nearest_;
  float largest_ = 0.0f;
};

// A row of codes in pixel order to the device's bit stream (the inverse of kernels::unpack_row):
// stream position p holds pixel x = 4 (p % 128) + p / 128, 11 bits at bit 11 p; eight codes fill
// 11 bytes.
void pack_row(const uint16_t* codes, uint8_t* row_bytes) {
  for (int group = 0; group < kRawWidth / 8; ++group) {
    const int p0 = 8 * group;
    const uint16_t* in = codes + 4 * (p0 & 127) + (p0 >> 7);
    uint64_t low = 0, high = 0;  // bits 0..63 and 64..87 of the group
    for (int j = 0; j < 8; ++j) {
      const uint64_t code = in[4 * j] & 2047u;
      const int bit = 11 * j;
      if (bit >= 64) {
        high |= code << (bit - 64);
      } else {
        low |= code << bit;
        if (bit + 11 > 64) high |= code >> (64 - bit);  // code 5 straddles the two
      }
    }
    uint8_t* out = row_bytes + 11 * group;
    for (int b = 0; b < 8; ++b) out[b] = static_cast<uint8_t>(low >> (8 * b));
    for (int b = 0; b < 3; ++b) out[8 + b] = static_cast<uint8_t>(high >> (8 * b));
  }
}

struct Complex {
  double re, im;
};
inline Complex operator*(Complex a, Complex b) {
  return {a.re * b.re - a.im * b.im, a.re * b.im + a.im * b.re};
}

}  // namespace

class PacketEncoder::Impl {
 public:
  Impl(const P0Tables& p0, const IrCalibration& calibration)
      : rays_(make_ray_tables(calibration)), phases_(make_phase_tables(p0, constants_)) {}

  Status encode(const DepthImage& depth, const IrImage& ir, std::vector<uint8_t>* packet) const {
    if (depth.width != kRawWidth || depth.height != kRawHeight ||
        depth.depth_m.size() != kRawPixels)
      return invalid_argument("packet encoder: depth image must be 512x424, got " +
                              std::to_string(depth.width) + "x" + std::to_string(depth.height));
    if (ir.width != kRawWidth || ir.height != kRawHeight || ir.amplitude.size() != kRawPixels)
      return invalid_argument("packet encoder: IR image must be 512x424, got " +
                              std::to_string(ir.width) + "x" + std::to_string(ir.height));
    packet->resize(kRawPacketBytes);
    // Sub-image 9 is not used; every byte of the others is written below.
    std::memset(packet->data() + 9 * kRawSubImageBytes, 0, kRawSubImageBytes);
    const double unambiguous = constants_.unambiguous_distance_mm;
    uint16_t codes[9][kRawWidth];
    for (int y = 0; y < kRawHeight; ++y) {
      const size_t image_row = static_cast<size_t>(kRawHeight - 1 - y) * kRawWidth;
      for (int x = 0; x < kRawWidth; ++x) {
        const size_t i = static_cast<size_t>(y) * kRawWidth + x;
        const float depth_m = depth.depth_m[image_row + x];
        const float intensity = ir.amplitude[image_row + x];
        int pixel_codes[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
        if (intensity >= 65535.0f) {
          std::fill(pixel_codes, pixel_codes + 9, kSaturatedCode);
        } else if (depth_m > 0.0f && intensity > 0.0f && rays_.z_mm_per_phase[i] > 0.0f) {
          const std::optional<double> units = range_units(depth_m * 1000.0, i, unambiguous);
          if (units)
            fill_codes(*units, intensity / constants_.ab_output_multiplier, i, pixel_codes);
        }
        for (int s = 0; s < 9; ++s) codes[s][x] = static_cast<uint16_t>(pixel_codes[s]);
      }
      const size_t storage = static_cast<size_t>(packet_storage_row(y)) * kRawRowBytes;
      for (int s = 0; s < 9; ++s) pack_row(codes[s], packet->data() + s * kRawSubImageBytes + storage);
    }
    return Status::ok();
  }

 private:
  // The unwrapped phase (in [0, 30): units of the whole range over 30) at which the decoder gives
  // `depth_mm` at pixel i: it maps phase P to z P / (1 - c / P), c the light source's offset term.
  std::optional<double> range_units(double depth_mm, size_t i, double unambiguous) const {
    const double z = rays_.z_mm_per_phase[i];
    const double c = z * rays_.x_scaled[i] * 90.0 / (4.0 * unambiguous * unambiguous * 8192.0);
    const double discriminant = depth_mm * depth_mm - 4.0 * z * depth_mm * c;
    if (discriminant < 0.0) return std::nullopt;
    const double phase = (depth_mm + std::sqrt(discriminant)) / (2.0 * z);
    const double units = phase / kPhasePerUnit;
    if (!(units > 0.0 && units < 30.0)) return std::nullopt;
    return units;
  }

  // Amplitude A_f per frequency such that the decoder's amplitude is `amplitude` for each.
  void fill_codes(double units, double amplitude, size_t i, int codes[9]) const {
    // The frequencies wrap 3, 15 and 2 times over the range (see kernels::unwrap_row): their
    // phases are 10, 2 and 15 times the phase of one wrap per 30 units. One cos/sin and powers
    // of it instead of three of each (the libm calls were most of the encoder's time).
    const double base = 2.0 * M_PI * units / 30.0;
    const Complex z1{std::cos(base), std::sin(base)};
    const Complex z2 = z1 * z1;
    const Complex z5 = z2 * z2 * z1;
    const Complex z10 = z5 * z5;
    const Complex rotation[3] = {z10, z2, z10 * z5};
    for (int f = 0; f < 3; ++f) {
      const double a = amplitude / constants_.ab_multiplier_per_frequency[f];
      for (int k = 0; k < 3; ++k) {
        // cos(alpha + phase), alpha = P0 + step k, from the decoder's tables.
        const double value = a * (phases_.cos_at(f, k, i) * rotation[f].re +
                                  phases_.neg_sin_at(f, k, i) * rotation[f].im);
        codes[3 * f + k] = codebook_.code_of(static_cast<float>(value));
      }
    }
  }

  const DecodeConstants constants_;  // before phases_, which are made from it
  const RayTables rays_;
  const PhaseTables phases_;
  const CodeBook codebook_;
};

Result<std::unique_ptr<PacketEncoder>> PacketEncoder::create(const P0Tables& p0,
                                                             const IrCalibration& calibration) {
  DF_RETURN_IF_ERROR(check_p0_tables(p0).with_context("packet encoder"));
  DF_RETURN_IF_ERROR(check_ir_calibration(calibration).with_context("packet encoder"));
  return std::unique_ptr<PacketEncoder>(
      new PacketEncoder(std::make_unique<Impl>(p0, calibration)));
}

PacketEncoder::PacketEncoder(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
PacketEncoder::~PacketEncoder() = default;

Status PacketEncoder::encode(const DepthImage& depth, const IrImage& ir,
                             std::vector<uint8_t>* packet) const {
  return impl_->encode(depth, ir, packet);
}

}  // namespace depthfuse::kinect2
