// The process-wide stop flag and eventfd (see signals.hpp). on_signal() runs in the signal handler,
// on whichever thread the kernel picks; everything else may be called from any thread.
#include "depthfuse/daemon/signals.hpp"

#include <poll.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <csignal>
#include <cstdint>
#include <mutex>

namespace depthfuse::daemon {

namespace {
std::atomic<int> g_signal{0};
std::atomic<bool> g_stop{false};
int g_event_fd = -1;

void on_signal(int sig) {
  // Only async-signal-safe calls here.
  g_signal.store(sig);
  g_stop.store(true);
  const uint64_t one = 1;
  if (g_event_fd >= 0) {
    const int saved = errno;
    ssize_t r = ::write(g_event_fd, &one, sizeof(one));
    (void)r;
    errno = saved;
  }
}
}  // namespace

ShutdownSignal& ShutdownSignal::install() {
  static ShutdownSignal instance;
  static std::once_flag once;
  std::call_once(once, [] {
    g_event_fd = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    struct sigaction sa {};
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sa.sa_flags = SA_RESTART;
    sigaction(SIGINT, &sa, nullptr);
    sigaction(SIGTERM, &sa, nullptr);
    std::signal(SIGPIPE, SIG_IGN);
  });
  return instance;
}

bool ShutdownSignal::stop_requested() const { return g_stop.load(); }
int ShutdownSignal::fd() const { return g_event_fd; }
int ShutdownSignal::signal_number() const { return g_signal.load(); }
void ShutdownSignal::request_stop() { on_signal(0); }

bool ShutdownSignal::sleep_for(double seconds) const {
  if (stop_requested()) return true;
  if (seconds <= 0) return false;
  pollfd p{g_event_fd, POLLIN, 0};
  const int ms = static_cast<int>(seconds * 1000.0 + 0.5);
  if (g_event_fd < 0) {
    ::usleep(static_cast<useconds_t>(seconds * 1e6));
  } else {
    ::poll(&p, 1, ms);
  }
  return stop_requested();
}

}  // namespace depthfuse::daemon
