// What the capture daemon is told on its command line, on top of the config.
#pragma once

#include <string>
#include <vector>

#include "depthfuse/app_config.hpp"
#include "depthfuse/daemon/args.hpp"
#include "depthfuse/lcm/frame_codec.hpp"
#include "depthfuse/status.hpp"
#include "pacer.hpp"

namespace depthfuse::capture {

struct CaptureOptions {
  std::string name = "capture";  // heartbeat name and command target
  std::string source_spec;       // as open_frame_source takes it
  RateChoice rate;
  bool loop = false;             // rewind a finite source at its end
  bool linger = false;           // keep running (state finished) when a finite source ends
  bool send_color = true;
  lcm::ColorEncodeOptions color;
  lcm::DepthEncodeOptions depth;
};

// The options that take a value and the flags capture_options() reads.
extern const std::vector<std::string> kCaptureOptionNames;
extern const std::vector<std::string> kCaptureFlagNames;

// --source, --rate, --loop, --name, --color, --depth-encoding, --depth-unit and --linger, the
// config's capture section where an option is not given. kInvalidArgument names a bad option.
Result<CaptureOptions> capture_options(const daemon::Args& args, const AppConfig& config);

}  // namespace depthfuse::capture
