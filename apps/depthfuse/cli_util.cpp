#include "cli_util.hpp"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>

namespace depthfuse::cli {

Args::Args(int argc, char** argv, const std::vector<std::string>& flags) {
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    if (a.size() > 2 && a.rfind("--", 0) == 0) {
      std::string name = a.substr(2), value;
      const size_t eq = name.find('=');
      if (eq != std::string::npos) {
        value = name.substr(eq + 1);
        name = name.substr(0, eq);
      } else if (std::find(flags.begin(), flags.end(), name) != flags.end()) {
        value = "1";
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

bool Args::get_int(const std::string& name, long* out, std::string* error) const {
  if (!has(name)) return true;
  const std::string v = get(name);
  char* end = nullptr;
  const long x = std::strtol(v.c_str(), &end, 10);
  if (v.empty() || *end) {
    *error = "--" + name + " expects an integer, got '" + v + "'";
    return false;
  }
  *out = x;
  return true;
}

bool Args::get_double(const std::string& name, double* out, std::string* error) const {
  if (!has(name)) return true;
  const std::string v = get(name);
  char* end = nullptr;
  const double x = std::strtod(v.c_str(), &end);
  if (v.empty() || *end || !std::isfinite(x)) {
    *error = "--" + name + " expects a number, got '" + v + "'";
    return false;
  }
  *out = x;
  return true;
}

std::string Args::unknown(const std::vector<std::string>& known) const {
  for (const auto& kv : values_)
    if (std::find(known.begin(), known.end(), kv.first) == known.end())
      return kv.first == "output" ? "-o" : "--" + kv.first;
  return "";
}

std::optional<AppConfig> load_config_or_report(const Args& args, const char* command) {
  if (!args.has("config")) return AppConfig{};
  auto c = load_app_config(args.get("config"));
  if (!c) {
    std::fprintf(stderr, "depthfuse %s: %s\n", command, c.status().message().c_str());
    return std::nullopt;
  }
  return *c;
}

Progress::Progress(FILE* out) : out_(out), tty_(isatty(fileno(out)) != 0) {}

void Progress::operator()(const std::string& stage, size_t done, size_t total) {
  if (total == 0) return;
  if (stage != stage_) {
    if (tty_ && !stage_.empty()) std::fputc('\n', out_);
    stage_ = stage;
    last_decile_ = -1;
  }
  const double f = static_cast<double>(done) / total;
  if (tty_) {
    const int width = 30, filled = static_cast<int>(f * width);
    std::fprintf(out_, "\r%-22s [%s%s] %zu/%zu", stage.c_str(), std::string(filled, '#').c_str(),
                 std::string(width - filled, ' ').c_str(), done, total);
    if (done == total) std::fputc('\n', out_), stage_.clear();
    std::fflush(out_);
  } else {
    const int decile = static_cast<int>(f * 10);
    if (decile != last_decile_) {
      last_decile_ = decile;
      std::fprintf(out_, "%s: %zu/%zu (%d%%)\n", stage.c_str(), done, total, decile * 10);
    }
  }
}

std::string describe_iteration(const BatchIterationReport& it, size_t frames) {
  char line[256];
  if (it.iteration == 0) {
    std::snprintf(line, sizeof line, "    0: points %zu, %.1f s\n", it.points, it.seconds);
  } else {
    std::snprintf(line, sizeof line,
                  "    %d: points %zu, registered %zu/%zu frames, max pose change %.2f mm / %.3f deg, "
                  "ICP fitness %.2f, rmse %.2f mm, %.1f s\n",
                  it.iteration, it.points, it.registered, frames, it.max_translation_change_m * 1000,
                  it.max_rotation_change_deg, it.mean_fitness, it.mean_rmse_m * 1000, it.seconds);
  }
  return line;
}

int fail(const char* command, const std::string& message) {
  std::fprintf(stderr, "depthfuse %s: %s\n", command, message.c_str());
  return 1;
}

}  // namespace depthfuse::cli
