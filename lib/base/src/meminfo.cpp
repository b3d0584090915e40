#include "depthfuse/base/meminfo.hpp"

#include <fstream>
#include <limits>
#include <string>

namespace depthfuse {

uint64_t available_memory_bytes() {
  std::ifstream in("/proc/meminfo");
  std::string key;
  uint64_t kib = 0;
  // Lines of "Key: value kB"; the unit is always kB.
  while (in >> key >> kib) {
    if (key == "MemAvailable:") return kib * 1024;
    in.ignore(std::numeric_limits<std::streamsize>::max(), '\n');
  }
  return 0;
}

}  // namespace depthfuse
