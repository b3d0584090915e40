#include "cli_util.hpp"

#include <unistd.h>

#include "depthfuse/base/log.hpp"
#include "depthfuse/base/meminfo.hpp"

DF_LOG_CATEGORY(Cli)

namespace depthfuse::cli {

daemon::Program offline_program(const std::string& name, const char* usage,
                                std::vector<std::string> options, std::vector<std::string> flags,
                                size_t max_positional, bool reads_config) {
  daemon::Program program;
  program.name = "depthfuse " + name;
  program.usage = "usage: " + std::string(usage) + "\n";
  program.options = std::move(options);
  program.flags = std::move(flags);
  program.max_positional = max_positional;
  program.reads_config = reads_config;
  program.uses_lcm = false;
  return program;
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

namespace {

std::string mib(uint64_t bytes) {
  char text[32];
  std::snprintf(text, sizeof text, "%.1f MiB", static_cast<double>(bytes) / (1 << 20));
  return text;
}

}  // namespace

Status check_frames_fit(uint64_t frames, uint64_t frame_bytes, const std::string& why,
                        const std::string& lower) {
  const uint64_t available = available_memory_bytes();
  if (!available || frames * frame_bytes <= available) return Status::ok();
  return invalid_argument(why + " holds every frame in memory: " + std::to_string(frames) +
                          " frames of " + mib(frame_bytes) + " need " + mib(frames * frame_bytes) +
                          ", more than the " + mib(available) + " available; " + lower);
}

uint64_t frame_bytes(const Frame& f) {
  return sizeof(Frame) + f.depth.depth_m.size() * sizeof(float) + f.color.rgb.size();
}

int fail(const std::string& message) {
  DF_LOG(Cli, Error) << message;
  return 1;
}

}  // namespace depthfuse::cli
