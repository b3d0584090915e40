// Facts about this process (see process_info.hpp), read when asked, from any thread.
#include "depthfuse/daemon/process_info.hpp"

#include <unistd.h>

#include <filesystem>
#include <fstream>

namespace depthfuse::daemon {

std::string host_name() {
  char name[256] = {0};
  if (::gethostname(name, sizeof(name) - 1) != 0) return "unknown";
  return name;
}

std::string installed_data_dir(const std::string& name) {
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  const std::filesystem::path prefix = ec ? std::filesystem::path("/usr") : exe.parent_path().parent_path();
  return (prefix / "share" / "depthfuse" / name).string();
}

int process_id() { return static_cast<int>(::getpid()); }

int64_t resident_memory_bytes() {
  std::ifstream in("/proc/self/statm");
  int64_t size_pages = 0, resident_pages = 0;
  if (!(in >> size_pages >> resident_pages)) return -1;
  return resident_pages * static_cast<int64_t>(::sysconf(_SC_PAGESIZE));
}

}  // namespace depthfuse::daemon
