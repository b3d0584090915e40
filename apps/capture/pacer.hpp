// When the capture daemon publishes each frame: at a fixed rate, as fast as the source delivers,
// or at the pace the frames were recorded. Owned and run by the capture thread (CaptureDaemon).
#pragma once

#include <chrono>
#include <cstdint>
#include <string>

#include "depthfuse/daemon/signals.hpp"
#include "depthfuse/frame_source.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse::capture {

// The --rate option.
struct RateChoice {
  enum class Kind {
    kDefault,   // the recorded pace for a recorded session, else the source's nominal rate, else
                // the config's capture.rate_hz
    kFixed,     // rate_hz
    kMax,       // as fast as possible
    kRecorded,  // the pace of the frames' recorded times
  };
  Kind kind = Kind::kDefault;
  double rate_hz = 0;
};

// "" (the default), a positive number of frames per second, "max" or "recorded".
Result<RateChoice> parse_rate(const std::string& text);

class Pacer {
 public:
  // `choice` made concrete for `source`; a rate of 0 (capture.rate_hz = 0) means as fast as
  // possible.
  Pacer(const RateChoice& choice, const FrameSource& source, double config_rate_hz);

  // "max rate", "recorded pace" or "<rate> Hz", for the log.
  std::string describe() const;

  // Waits until `frame`, the one source.next() returned last, is due. True when a stop was
  // requested during the wait.
  bool wait_for_turn(const FrameSource& source, const Frame& frame,
                     const daemon::ShutdownSignal& shutdown);

  // After a pause: the next frame is due at once, the time line starts over from now.
  void resume();
  // After the source rewound: its recorded times start over.
  void rewound() { have_prev_ = false; }

 private:
  using Clock = std::chrono::steady_clock;
  enum class Mode { kFixed, kMax, kRecorded };

  bool sleep_until_due(const daemon::ShutdownSignal& shutdown) const;

  Mode mode_ = Mode::kFixed;
  double rate_hz_ = 0;
  Clock::duration period_{};
  Clock::time_point next_due_ = Clock::now();
  int64_t prev_utime_ = 0;  // kRecorded: the recorded time of the previous frame
  bool have_prev_ = false;
};

}  // namespace depthfuse::capture
