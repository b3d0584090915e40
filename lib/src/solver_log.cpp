#include "solver_log.hpp"

#include <mutex>
#include <string_view>

#include <glog/logging.h>

#include "depthfuse/base/log.hpp"

namespace depthfuse {
namespace {

DF_LOG_CATEGORY(Solver)

class ToLevelledLog final : public google::LogSink {
 public:
  void send(google::LogSeverity severity, const char* /*full_filename*/, const char* base_filename,
            int line, const google::LogMessageTime& /*time*/, const char* message,
            size_t message_len) override {
    const std::string_view text(message, message_len);
    if (severity >= google::GLOG_ERROR) {
      DF_LOG(Solver, Error) << "Ceres (" << base_filename << ":" << line << "): " << text;
    } else {
      DF_LOG(Solver, Warning) << "Ceres (" << base_filename << ":" << line << "): " << text;
    }
  }
};

}  // namespace

void route_solver_log() {
  static std::once_flag once;
  std::call_once(once, [] {
    // A program that configured glog itself keeps its own settings.
    if (google::IsGoogleLoggingInitialized()) return;
    // Until glog is initialised it writes every message to stderr, whatever its flags say. glog
    // keeps the pointer: a literal lives long enough.
    google::InitGoogleLogging("depthfuse");
    for (int severity = 0; severity < google::NUM_SEVERITIES; ++severity) {
      google::SetLogDestination(severity, "");  // no log files
    }
    FLAGS_stderrthreshold = google::GLOG_FATAL;  // a failed check aborts: say why on stderr
    FLAGS_minloglevel = google::GLOG_WARNING;    // Ceres's info lines are progress, not news
    static ToLevelledLog sink;
    google::AddLogSink(&sink);
  });
}

}  // namespace depthfuse
