// Internal: the loader's record of every key it knows, for tests that keep the shipped
// config/depthfuse.toml, the documentation and the struct defaults from drifting apart.
// Free of toml++ so that tests can include it without the parser's headers.
#pragma once

#include <string>
#include <vector>

#include "depthfuse/app_config.hpp"
#include "depthfuse/toml/key_trace.hpp"

namespace depthfuse::app_config_detail {

using strict_toml::KeyTrace;

// parse_app_config, also listing every key the loader read (in reading order).
Result<AppConfig> parse_app_config_traced(const std::string& toml_text, const std::string& origin,
                                          std::vector<KeyTrace>* trace);

}  // namespace depthfuse::app_config_detail
