#include "depthfuse/kinect2/raw_depth.hpp"

#include <cmath>
#include <cstring>
#include <string>

namespace depthfuse::kinect2 {

namespace {

std::array<int16_t, 2048> make_code_table() {
  // Codes 0..1023 are non-negative values on a scale whose step doubles every 128 codes after the
  // first 256; codes 1024 + c are their negatives; code 1024 itself means saturated.
  std::array<int16_t, 2048> table{};
  int value = 0;
  for (int code = 0; code < 1024; ++code) {
    table[code] = static_cast<int16_t>(value);
    table[1024 + code] = static_cast<int16_t>(-value);
    value += 1 << (code / 128 - (code >= 128 ? 1 : 0));
  }
  table[1024] = kRawSaturated;
  return table;
}

void put_u16(uint8_t* at, uint16_t value) {
  at[0] = static_cast<uint8_t>(value & 0xff);
  at[1] = static_cast<uint8_t>(value >> 8);
}

uint16_t get_u16(const uint8_t* at) { return static_cast<uint16_t>(at[0] | (at[1] << 8)); }

}  // namespace

const std::array<int16_t, 2048>& code_to_correlation() {
  static const std::array<int16_t, 2048> table = make_code_table();
  return table;
}

Result<P0Tables> parse_p0_response(const uint8_t* bytes, size_t size) {
  if (bytes == nullptr || size == 0) return invalid_argument("P0 tables: no data (missing P0 tables)");
  if (size < kP0ResponseBytes)
    return invalid_argument("P0 tables: response of " + std::to_string(size) +
                            " bytes is too short, expected " + std::to_string(kP0ResponseBytes));
  P0Tables tables;
  const uint8_t* at = bytes + kP0ResponseHeaderBytes;
  for (auto& table : tables.table) {
    at += 2;
    table.resize(kRawPixels);
    for (size_t i = 0; i < kRawPixels; ++i) table[i] = get_u16(at + 2 * i);
    at += 2 * kRawPixels + 2;
  }
  return tables;
}

Status check_p0_tables(const P0Tables& tables) {
  if (tables.empty()) return invalid_argument("missing P0 tables");
  for (int f = 0; f < 3; ++f)
    if (tables.table[f].size() != kRawPixels)
      return invalid_argument("P0 table " + std::to_string(f) + " has " +
                              std::to_string(tables.table[f].size()) + " entries, expected " +
                              std::to_string(kRawPixels));
  return Status::ok();
}

std::vector<uint8_t> p0_response(const P0Tables& tables) {
  std::vector<uint8_t> bytes(kP0ResponseBytes, 0);
  uint8_t* at = bytes.data() + kP0ResponseHeaderBytes;
  for (const auto& table : tables.table) {
    at += 2;
    for (size_t i = 0; i < kRawPixels && i < table.size(); ++i) put_u16(at + 2 * i, table[i]);
    at += 2 * kRawPixels + 2;
  }
  return bytes;
}

Status check_ir_calibration(const IrCalibration& c) {
  const float values[] = {c.fx, c.fy, c.cx, c.cy, c.k1, c.k2, c.k3, c.p1, c.p2};
  for (float v : values)
    if (!std::isfinite(v))
      return invalid_argument("IR calibration: every parameter must be finite, got fx=" +
                              std::to_string(c.fx) + " fy=" + std::to_string(c.fy) +
                              " cx=" + std::to_string(c.cx) + " cy=" + std::to_string(c.cy) +
                              " k1=" + std::to_string(c.k1) + " k2=" + std::to_string(c.k2) +
                              " k3=" + std::to_string(c.k3) + " p1=" + std::to_string(c.p1) +
                              " p2=" + std::to_string(c.p2));
  if (!(c.fx > 0.0f && c.fy > 0.0f))
    return invalid_argument("IR calibration: focal lengths must be > 0, got fx=" +
                            std::to_string(c.fx) + " fy=" + std::to_string(c.fy));
  return Status::ok();
}

}  // namespace depthfuse::kinect2
