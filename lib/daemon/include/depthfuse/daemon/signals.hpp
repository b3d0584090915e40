// SIGINT/SIGTERM as a flag and a file descriptor: a daemon's loops poll stop_requested() (or wait
// on fd() together with LCM's socket) and shut down cleanly.
#pragma once

namespace depthfuse::daemon {

class ShutdownSignal {
 public:
  // Installs handlers for SIGINT and SIGTERM (once per process) and ignores SIGPIPE.
  static ShutdownSignal& install();

  bool stop_requested() const;
  // Readable once a signal arrived (an eventfd); never reset.
  int fd() const;
  // The signal number that arrived, 0 if none.
  int signal_number() const;
  // Same as receiving a signal (tests, fatal errors).
  void request_stop();

  // Sleeps up to `seconds`, returning early (true) when a stop was requested.
  bool sleep_for(double seconds) const;

 private:
  ShutdownSignal() = default;
};

}  // namespace depthfuse::daemon
