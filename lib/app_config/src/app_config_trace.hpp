// Internal: the loader's record of every key it knows, for tests that keep the shipped
// config/depthfuse.toml, the documentation and the struct defaults from drifting apart.
// Free of toml++ so that tests can include it without the parser's headers.
#pragma once

#include <string>
#include <vector>

#include "depthfuse/app_config.hpp"

namespace depthfuse::app_config_detail {

// One key the loader looked up, with the value it ended with.
struct KeyTrace {
  std::string key;        // full dotted key, e.g. "fusion_daemon.memory_budget_mib"
  std::string value;      // exact text of the final value (doubles with 17 significant digits)
  bool from_file = false;  // false: the key was absent and kept its default
};

// parse_app_config, also listing every key the loader read (in reading order).
Result<AppConfig> parse_app_config_traced(const std::string& toml_text, const std::string& origin,
                                          std::vector<KeyTrace>* trace);

}  // namespace depthfuse::app_config_detail
