// A depth PNG in a TUM folder (depthfuse reconstruct and the replay source read them), into the
// replay source: never a crash, and a small file that declares a huge image is refused before it
// is decoded. The input is the whole PNG; the folder around it is fixed (64x48 camera.toml).
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>

#include "depthfuse/replay/tum_source.hpp"

namespace {

std::string make_folder() {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("fuzz_tum_png." + std::to_string(::getpid()));
  std::filesystem::create_directories(dir / "depth");
  std::ofstream(dir / "depth.txt") << "1.000000 depth/1.png\n";
  std::ofstream(dir / "camera.toml")
      << "[camera]\nwidth = 64\nheight = 48\nfx = 50.0\nfy = 50.0\ncx = 31.5\ncy = 23.5\n";
  return dir.string();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const std::string folder = make_folder();
  std::ofstream(folder + "/depth/1.png", std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  auto source = depthfuse::replay::TumSource::open(folder, depthfuse::replay::TumReplayConfig{});
  if (source) (void)(*source)->next();
  return 0;
}
