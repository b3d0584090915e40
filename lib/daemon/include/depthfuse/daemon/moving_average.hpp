// The exponential moving average behind the daemons' "_mean" heartbeat figures, written once: each
// new value weighs kMeanWeight, so that a mean follows about the last 10 values.
#pragma once

#include <atomic>

namespace depthfuse::daemon {

inline constexpr double kMeanWeight = 0.1;

inline void ewma(double* mean, double value) { *mean += kMeanWeight * (value - *mean); }

// One thread updates it, any other may read it (the heartbeat's).
inline void ewma(std::atomic<double>* mean, double value) {
  const double m = mean->load();
  mean->store(m + kMeanWeight * (value - m));
}

}  // namespace depthfuse::daemon
