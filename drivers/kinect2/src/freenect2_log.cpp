#include "freenect2_log.hpp"

#include <cstdlib>
#include <mutex>

#include <libfreenect2/logger.h>

#include "depthfuse/base/log.hpp"

DF_LOG_CATEGORY(Kinect2)

namespace depthfuse::kinect2 {

namespace {

std::mutex g_error_mutex;
std::string g_last_error;

class Freenect2Log final : public libfreenect2::Logger {
 public:
  explicit Freenect2Log(Level print_level) { level_ = print_level; }

  void log(Level level, const std::string& message) override {
    if (level == Error) {
      std::lock_guard<std::mutex> lock(g_error_mutex);
      g_last_error = message;
    }
    if (level > level_) return;
    // What is shown is chosen above (LIBFREENECT2_LOGGER_LEVEL), so Info and Debug are logged as
    // Info: --log-level need not repeat the choice.
    switch (level) {
      case Error: DF_LOG(Kinect2, Error) << "libfreenect2: " << message; break;
      case Warning: DF_LOG(Kinect2, Warning) << "libfreenect2: " << message; break;
      default: DF_LOG(Kinect2, Info) << "libfreenect2 " << level2str(level) << ": " << message;
    }
  }
};

}  // namespace

void install_freenect2_log() {
  static std::once_flag once;
  std::call_once(once, [] {
    // libfreenect2 prints at Info by default, which floods a daemon's journal at 30 Hz.
    const bool user_level = std::getenv("LIBFREENECT2_LOGGER_LEVEL") != nullptr;
    const auto level = user_level ? libfreenect2::Logger::getDefaultLevel()
                                  : libfreenect2::Logger::Warning;
    // The Error capture must work whatever is printed: log() sees every message because the
    // level filter is ours (libfreenect2 hands all messages to the logger).
    libfreenect2::setGlobalLogger(new Freenect2Log(level));
  });
}

std::string last_freenect2_error() {
  std::lock_guard<std::mutex> lock(g_error_mutex);
  return g_last_error;
}

void clear_last_freenect2_error() {
  std::lock_guard<std::mutex> lock(g_error_mutex);
  g_last_error.clear();
}

}  // namespace depthfuse::kinect2
