// Facts about this process for heartbeats: host name, pid, resident memory, uptime.
#pragma once

#include <chrono>
#include <cstdint>
#include <string>

namespace depthfuse::daemon {

std::string host_name();
int process_id();
// Resident set size in bytes from /proc/self/statm, -1 when it cannot be read.
int64_t resident_memory_bytes();

class Uptime {
 public:
  Uptime() : start_(std::chrono::steady_clock::now()) {}
  double seconds() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }

 private:
  std::chrono::steady_clock::time_point start_;
};

}  // namespace depthfuse::daemon
