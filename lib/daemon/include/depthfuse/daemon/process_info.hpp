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
// <the executable's folder>/../share/depthfuse/<name>: where the package installs the program's
// data, and where the build puts it (build/bin, build/share), so one rule finds it in both.
std::string installed_data_dir(const std::string& name);

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
