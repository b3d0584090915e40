// The appliance's config file (every daemon and the CLI read it), into the config reader: never a
// crash, and every value it accepts within its documented range. The input is the file's text.
#include <cstddef>
#include <cstdint>
#include <string>

#include "depthfuse/app_config.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  auto config = depthfuse::parse_app_config(text, "fuzz.toml");
  if (config && !(config->fusion.queue_capacity_frames >= 1 && config->fusion.max_frame_width >= 1 &&
                  config->fusion.checkpoint_interval_s > 0))
    __builtin_trap();
  return 0;
}
