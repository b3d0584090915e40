// Small helpers shared by the CLI's subcommands: their start-up, progress, memory checks, reports.
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "depthfuse/daemon/args.hpp"
#include "depthfuse/daemon/startup.hpp"
#include "depthfuse/pipeline.hpp"

namespace depthfuse::cli {

// The command line, as every depthfuse program parses it (lib/daemon).
using Args = daemon::Args;

// The most rounds of re-registration a run may ask for (--iterations): the batch loop stops early
// once the poses settle, and a larger number is a typo, not a plan.
inline constexpr long kMaxIterations = 1000;

// The start-up of an offline subcommand (daemon::Startup): named "depthfuse <name>" in its log
// lines, `usage` (one line or more, without "usage: ") as --help prints it, no LCM options;
// --config only when it reads the appliance's config file.
daemon::Program offline_program(const std::string& name, const char* usage,
                                std::vector<std::string> options, std::vector<std::string> flags,
                                size_t max_positional, bool reads_config);

// For a run that holds every frame of its input (the batch pipeline's rounds go over all of them):
// an error when `frames` frames of `frame_bytes` each do not fit in the memory this machine has
// available now, with both figures, `why` (what holds them) and `lower` (how to take fewer).
Status check_frames_fit(uint64_t frames, uint64_t frame_bytes, const std::string& why,
                        const std::string& lower);
// The memory a frame holds: depth, colour and the frame itself.
uint64_t frame_bytes(const Frame& frame);

// A bar on a terminal, a plain line every 10 % otherwise (logs, CI).
class Progress {
 public:
  explicit Progress(FILE* out = stderr);
  void operator()(const std::string& stage, size_t done, size_t total);
  ProgressFn fn() { return [this](const std::string& s, size_t d, size_t t) { (*this)(s, d, t); }; }

 private:
  FILE* out_;
  bool tty_;
  std::string stage_;
  int last_decile_ = -1;
};

// One line of a batch run's report: "    1: points ..., registered 18/20 frames, ...". Iteration 0 is
// the first fusion, without registration.
std::string describe_iteration(const BatchIterationReport& it, size_t frames);

// Logs `message` as an error ("depthfuse <command>: ...": main() names the log after the command)
// and returns exit code 1.
int fail(const std::string& message);

}  // namespace depthfuse::cli
