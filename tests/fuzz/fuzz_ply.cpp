// A PLY file from anywhere (depthfuse eval and refine read them), into read_ply: never a crash,
// never an allocation the file's bytes do not justify. The input is the whole file.
#include <sys/mman.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <string>

#include "depthfuse/ply.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  // An in-memory file: no disk traffic per run, and read_ply still reads it through a path.
  static const int fd = memfd_create("fuzz_ply", 0);
  static const std::string path = "/proc/self/fd/" + std::to_string(fd);
  if (fd < 0 || ftruncate(fd, 0) != 0 || pwrite(fd, data, size, 0) != static_cast<ssize_t>(size))
    __builtin_trap();
  (void)depthfuse::read_ply(path);
  return 0;
}
