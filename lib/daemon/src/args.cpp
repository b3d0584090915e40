// The command line as every program parses it (see args.hpp). Runs once, on the main thread, at
// start-up.
#include "depthfuse/daemon/args.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <sstream>

namespace depthfuse::daemon {
namespace {

bool contains(const std::vector<std::string>& names, const std::string& name) {
  return std::find(names.begin(), names.end(), name) != names.end();
}

std::string format_bound(double v) {
  std::ostringstream out;
  out << v;
  return out.str();
}

}  // namespace

bool NumberRange::contains(double v) const {
  return (min_open ? v > min : v >= min) && (max_open ? v < max : v <= max);
}

std::string NumberRange::text() const {
  const bool low = std::isfinite(min), high = std::isfinite(max);
  if (low && !high) return std::string(min_open ? " > " : " >= ") + format_bound(min);
  if (!low && high) return std::string(max_open ? " < " : " <= ") + format_bound(max);
  if (!low && !high) return "";
  return std::string(" in ") + (min_open ? "(" : "[") + format_bound(min) + ", " +
         format_bound(max) + (max_open ? ")" : "]");
}

NumberRange positive() { return {0.0, std::numeric_limits<double>::infinity(), true, false}; }
NumberRange closed(double lo, double hi) { return {lo, hi, false, false}; }
NumberRange open_closed(double lo, double hi) { return {lo, hi, true, false}; }

Args::Args(int argc, char** argv, const std::vector<std::string>& flags,
           const std::vector<std::string>& optional_values) {
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "-h") {
      values_["help"] = "1";
    } else if (a.size() > 2 && a.rfind("--", 0) == 0) {
      std::string name = a.substr(2), value;
      const size_t eq = name.find('=');
      if (eq != std::string::npos) {
        value = name.substr(eq + 1);
        name = name.substr(0, eq);
      } else if (name == "help" || contains(flags, name)) {
        value = "1";
      } else if (contains(optional_values, name)) {
        if (i + 1 < argc && argv[i + 1][0] != '-') value = argv[++i];
      } else if (i + 1 < argc) {
        value = argv[++i];
      } else {
        error_ = "option --" + name + " needs a value";
        return;
      }
      values_[name] = value;
    } else if (a == "-o") {
      if (i + 1 >= argc) {
        error_ = "option -o needs a value";
        return;
      }
      values_["output"] = argv[++i];
    } else {
      positional_.push_back(a);
    }
  }
}

std::string Args::get(const std::string& name, const std::string& fallback) const {
  auto it = values_.find(name);
  return it == values_.end() ? fallback : it->second;
}

bool Args::get_int(const std::string& name, long* out, std::string* error,
                   const NumberRange& range) const {
  if (!has(name)) return true;
  const std::string v = get(name);
  char* end = nullptr;
  errno = 0;
  const long x = std::strtol(v.c_str(), &end, 10);
  if (v.empty() || *end || errno == ERANGE || !range.contains(static_cast<double>(x))) {
    *error = "--" + name + " expects an integer" + range.text() + ", got '" + v + "'";
    return false;
  }
  *out = x;
  return true;
}

bool Args::get_double(const std::string& name, double* out, std::string* error,
                      const NumberRange& range) const {
  if (!has(name)) return true;
  const std::string v = get(name);
  char* end = nullptr;
  const double x = std::strtod(v.c_str(), &end);
  if (v.empty() || *end || !std::isfinite(x) || !range.contains(x)) {
    *error = "--" + name + " expects a number" + range.text() + ", got '" + v + "'";
    return false;
  }
  *out = x;
  return true;
}

std::string Args::unknown(const std::vector<std::string>& known) const {
  for (const auto& kv : values_)
    if (kv.first != "help" && !contains(known, kv.first))
      return kv.first == "output" ? "-o" : "--" + kv.first;
  return "";
}

}  // namespace depthfuse::daemon
