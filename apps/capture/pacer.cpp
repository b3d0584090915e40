// The capture daemon's pacing (see pacer.hpp); runs on the capture thread only.
#include "pacer.hpp"

#include <cmath>
#include <cstdlib>

namespace depthfuse::capture {
namespace {

// Recorded frames further apart than this (a gap in the recording, or times that jump back) are
// not waited for: the time line starts over at the later frame.
constexpr double kMaxRecordedGapS = 5.0;
// A fixed-rate daemon this many periods behind (a slow source) drops the lost time instead of
// publishing a burst to catch up.
constexpr int kMaxPeriodsBehind = 10;

}  // namespace

Result<RateChoice> parse_rate(const std::string& text) {
  RateChoice choice;
  if (text.empty()) return choice;
  if (text == "max") {
    choice.kind = RateChoice::Kind::kMax;
  } else if (text == "recorded") {
    choice.kind = RateChoice::Kind::kRecorded;
  } else {
    char* end = nullptr;
    choice.kind = RateChoice::Kind::kFixed;
    choice.rate_hz = std::strtod(text.c_str(), &end);
    if (*end != '\0' || !(choice.rate_hz > 0) || !std::isfinite(choice.rate_hz))
      return invalid_argument("--rate '" + text + "' is not a positive number, max or recorded");
  }
  return choice;
}

Pacer::Pacer(const RateChoice& choice, const FrameSource& source, double config_rate_hz)
    : rate_hz_(config_rate_hz) {
  using Kind = RateChoice::Kind;
  if (choice.kind == Kind::kMax) {
    mode_ = Mode::kMax;
  } else if (choice.kind == Kind::kRecorded ||
             (choice.kind == Kind::kDefault && source.paced_as_recorded())) {
    mode_ = Mode::kRecorded;
  } else if (choice.kind == Kind::kFixed) {
    rate_hz_ = choice.rate_hz;
  } else if (auto nominal = source.nominal_rate_hz()) {
    rate_hz_ = *nominal;
  }
  if (mode_ == Mode::kFixed && !(rate_hz_ > 0)) mode_ = Mode::kMax;
  if (mode_ == Mode::kFixed)
    period_ = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / rate_hz_));
}

std::string Pacer::describe() const {
  switch (mode_) {
    case Mode::kMax: return "max rate";
    case Mode::kRecorded: return "recorded pace";
    case Mode::kFixed: break;
  }
  return std::to_string(rate_hz_) + " Hz";
}

void Pacer::resume() {
  next_due_ = Clock::now();
  have_prev_ = false;
}

bool Pacer::sleep_until_due(const daemon::ShutdownSignal& shutdown) const {
  const auto now = Clock::now();
  return next_due_ > now &&
         shutdown.sleep_for(std::chrono::duration<double>(next_due_ - now).count());
}

bool Pacer::wait_for_turn(const FrameSource& source, const Frame& frame,
                          const daemon::ShutdownSignal& shutdown) {
  switch (mode_) {
    case Mode::kMax:
      return false;
    case Mode::kFixed: {
      next_due_ += period_;
      const auto now = Clock::now();
      if (now - next_due_ > kMaxPeriodsBehind * period_) next_due_ = now;
      return sleep_until_due(shutdown);
    }
    case Mode::kRecorded: {
      const int64_t utime = source.recorded_utime(frame);
      const double dt_s = (utime - prev_utime_) * 1e-6;
      prev_utime_ = utime;
      const bool follows = have_prev_ && dt_s > 0 && dt_s < kMaxRecordedGapS;
      have_prev_ = true;
      if (!follows) {
        next_due_ = Clock::now();
        return false;
      }
      next_due_ += std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(dt_s));
      return sleep_until_due(shutdown);
    }
  }
  return false;
}

}  // namespace depthfuse::capture
