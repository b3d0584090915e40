// Writing the TOML of scenes and generator settings: doubles that read back exactly, quoted
// strings. (Reading goes through the strict reader, lib/toml.)
#pragma once

#include <Eigen/Core>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>
#include <string_view>

namespace depthfuse::synthetic::toml_write {

// Shortest text that reads back as the same double, always with TOML float syntax.
inline std::string format_double(double v) {
  if (std::isnan(v)) return "nan";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  char buf[64];
  const auto res = std::to_chars(buf, buf + sizeof(buf), v);
  std::string s(buf, res.ptr);
  if (s.find_first_of(".eEn") == std::string::npos) s += ".0";
  // TOML wants a digit before the exponent's mantissa dot and no bare "1e5"-style ambiguity:
  // to_chars gives "1e+20", which TOML accepts as a float.
  return s;
}

inline std::string format_vec(const Eigen::Vector3d& v) {
  return "[" + format_double(v.x()) + ", " + format_double(v.y()) + ", " + format_double(v.z()) +
         "]";
}

inline std::string quote(std::string_view s) {
  std::string out = "\"";
  for (char c : s) {
    switch (c) {
      case '"':
        out += "\\\"";
        break;
      case '\\':
        out += "\\\\";
        break;
      case '\n':
        out += "\\n";
        break;
      case '\t':
        out += "\\t";
        break;
      case '\r':
        out += "\\r";
        break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          char buf[8];
          std::snprintf(buf, sizeof(buf), "\\u%04x", static_cast<unsigned>(c));
          out += buf;
        } else {
          out += c;
        }
    }
  }
  return out + "\"";
}

}  // namespace depthfuse::synthetic::toml_write
