// The strict reader's record of every key it looked up (TableReader's `trace`), for tests that keep
// a shipped file, its documentation and the struct defaults from drifting apart. Free of toml++ so
// that tests can include it without the parser's headers.
#pragma once

#include <string>

namespace depthfuse::strict_toml {

// One key the reader looked up, with the value it ended with.
struct KeyTrace {
  std::string key;         // full dotted key, e.g. "fusion_daemon.memory_budget_mib"
  std::string value;       // exact text of the final value (doubles with 17 significant digits)
  bool from_file = false;  // false: the key was absent and kept its default
};

}  // namespace depthfuse::strict_toml
