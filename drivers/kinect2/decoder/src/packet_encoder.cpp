#include "depthfuse/kinect2/packet_encoder.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <optional>

#include "decoder_tables.hpp"

namespace depthfuse::kinect2 {

namespace {

constexpr int kSaturatedCode = 1024;

// Wraps of each frequency's phase over the unambiguous range (see kernels::unwrap_row).
constexpr float kWraps[3] = {3.0f, 15.0f, 2.0f};
// The decoder's final phase is this many times the unwrapped phase in units of the whole range
// over 30 (its averaging constants, 0.9 * 0.333333).
constexpr double kPhasePerUnit = (0.5 + 0.333333 + 0.066667) * 0.333333;

// Nearest 11-bit code of a correlation value (never the saturation code).
class CodeBook {
 public:
  CodeBook() {
    const auto& table = code_to_correlation();
    for (int code = 0; code < 1024; ++code) positive_[code] = table[code];
  }

  int code_of(float value) const {
    const float magnitude = std::min(std::abs(value), static_cast<float>(positive_[1023]));
    const auto* upper = std::lower_bound(positive_, positive_ + 1024, magnitude);
    int code = static_cast<int>(upper - positive_);
    if (code > 0 && (code == 1024 || magnitude - positive_[code - 1] < positive_[code] - magnitude))
      --code;
    return (value < 0.0f && code > 0) ? 1024 + code : code;
  }

 private:
  float positive_[1024];
};

void put_code(uint8_t* row, int x, int code) {
  const int position = (x & 3) * 128 + (x >> 2);
  const int bit = 11 * position;
  const uint32_t shifted = static_cast<uint32_t>(code) << (bit & 7);
  uint8_t* at = row + (bit >> 3);
  at[0] |= static_cast<uint8_t>(shifted & 0xff);
  at[1] |= static_cast<uint8_t>((shifted >> 8) & 0xff);
  if ((bit & 7) > 5) at[2] |= static_cast<uint8_t>((shifted >> 16) & 0xff);
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
    packet->assign(kRawPacketBytes, 0);
    const double unambiguous = constants_.unambiguous_distance_mm;
    for (int y = 0; y < kRawHeight; ++y) {
      const size_t storage = static_cast<size_t>(packet_storage_row(y)) * kRawRowBytes;
      const size_t image_row = static_cast<size_t>(kRawHeight - 1 - y) * kRawWidth;
      for (int x = 0; x < kRawWidth; ++x) {
        const size_t i = static_cast<size_t>(y) * kRawWidth + x;
        const float depth_m = depth.depth_m[image_row + x];
        const float intensity = ir.amplitude[image_row + x];
        int codes[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
        if (intensity >= 65535.0f) {
          std::fill(codes, codes + 9, kSaturatedCode);
        } else if (depth_m > 0.0f && intensity > 0.0f && rays_.z_mm_per_phase[i] > 0.0f) {
          const std::optional<double> units = range_units(depth_m * 1000.0, i, unambiguous);
          if (units) fill_codes(*units, intensity / constants_.ab_output_multiplier, i, codes);
        }
        for (int s = 0; s < 9; ++s)
          put_code(packet->data() + s * kRawSubImageBytes + storage, x, codes[s]);
      }
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
    for (int f = 0; f < 3; ++f) {
      const double cycles = units / kWraps[f];
      const double phase = 2.0 * M_PI * (cycles - std::floor(cycles));
      const double a = amplitude / constants_.ab_multiplier_per_frequency[f];
      const double cos_phase = std::cos(phase), sin_phase = std::sin(phase);
      for (int k = 0; k < 3; ++k) {
        // cos(alpha + phase), alpha = P0 + step k, from the decoder's tables.
        const double value =
            a * (phases_.cos_at(f, k, i) * cos_phase + phases_.neg_sin_at(f, k, i) * sin_phase);
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
