// Small helpers to write and read the TOML of scenes and generator settings: exact doubles out,
// strict keys in, errors with file and line.
#pragma once

#include <toml++/toml.h>

#include <Eigen/Core>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <initializer_list>
#include <string>
#include <string_view>

#include "depthfuse/status.hpp"

namespace depthfuse::synthetic::toml_util {

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

// "<origin>:<line>: " for messages about a node.
inline std::string where(const std::string& origin, const toml::node& node) {
  const auto line = node.source().begin.line;
  return line > 0 ? origin + ":" + std::to_string(line) + ": " : origin + ": ";
}

inline Status check_keys(const toml::table& table, std::initializer_list<std::string_view> allowed,
                         const std::string& origin, const std::string& table_name) {
  for (auto&& [key, node] : table) {
    bool ok = false;
    for (std::string_view a : allowed) ok = ok || key.str() == a;
    if (!ok)
      return invalid_argument(where(origin, node) + "unknown key '" + std::string(key.str()) +
                              "' in " + table_name);
  }
  return Status::ok();
}

inline Status read_double(const toml::table& t, std::string_view key, const std::string& origin,
                          double* out) {
  const toml::node* n = t.get(key);
  if (!n) return Status::ok();
  if (auto v = n->value<double>()) {
    *out = *v;
    return Status::ok();
  }
  return invalid_argument(where(origin, *n) + "'" + std::string(key) + "' must be a number");
}

inline Status read_bool(const toml::table& t, std::string_view key, const std::string& origin,
                        bool* out) {
  const toml::node* n = t.get(key);
  if (!n) return Status::ok();
  if (auto v = n->value_exact<bool>()) {
    *out = *v;
    return Status::ok();
  }
  return invalid_argument(where(origin, *n) + "'" + std::string(key) + "' must be true or false");
}

inline Status read_int(const toml::table& t, std::string_view key, const std::string& origin,
                       int64_t* out) {
  const toml::node* n = t.get(key);
  if (!n) return Status::ok();
  if (auto v = n->value_exact<int64_t>()) {
    *out = *v;
    return Status::ok();
  }
  return invalid_argument(where(origin, *n) + "'" + std::string(key) + "' must be an integer");
}

inline Status read_string(const toml::table& t, std::string_view key, const std::string& origin,
                          std::string* out) {
  const toml::node* n = t.get(key);
  if (!n) return Status::ok();
  if (auto v = n->value_exact<std::string>()) {
    *out = *v;
    return Status::ok();
  }
  return invalid_argument(where(origin, *n) + "'" + std::string(key) + "' must be a string");
}

// An array of exactly `count` numbers.
inline Status read_numbers(const toml::table& t, std::string_view key, const std::string& origin,
                           size_t count, double* out, bool required) {
  const toml::node* n = t.get(key);
  if (!n) {
    if (!required) return Status::ok();
    return invalid_argument(where(origin, t) + "missing '" + std::string(key) + "'");
  }
  const toml::array* a = n->as_array();
  if (!a || a->size() != count)
    return invalid_argument(where(origin, *n) + "'" + std::string(key) + "' must be an array of " +
                            std::to_string(count) + " numbers");
  for (size_t i = 0; i < count; ++i) {
    auto v = a->get(i)->value<double>();
    if (!v)
      return invalid_argument(where(origin, *n) + "'" + std::string(key) +
                              "' must be an array of " + std::to_string(count) + " numbers");
    out[i] = *v;
  }
  return Status::ok();
}

inline Status read_vec3(const toml::table& t, std::string_view key, const std::string& origin,
                        Eigen::Vector3d* out, bool required) {
  double v[3] = {(*out)[0], (*out)[1], (*out)[2]};
  DF_RETURN_IF_ERROR(read_numbers(t, key, origin, 3, v, required));
  *out = Eigen::Vector3d(v[0], v[1], v[2]);
  return Status::ok();
}

// Parses TOML text into a table; syntax errors come back with origin and line.
inline Result<toml::table> parse(const std::string& text, const std::string& origin) {
  try {
    return toml::parse(text, origin);
  } catch (const toml::parse_error& e) {
    return invalid_argument(origin + ":" + std::to_string(e.source().begin.line) + ": " +
                            std::string(e.description()));
  }
}

}  // namespace depthfuse::synthetic::toml_util
