// The two clocks of depthfuse. Wall time in microseconds (`utime`, LCM's convention) stamps what
// leaves the process; the monotonic clock measures intervals, which wall-clock steps must not bend.
#pragma once

#include <cstdint>

namespace depthfuse {

// Microseconds since the Unix epoch (CLOCK_REALTIME).
int64_t now_utime();

// Nanoseconds of the monotonic clock (CLOCK_MONOTONIC); only differences mean anything.
int64_t steady_ns();

// Nanoseconds of CPU time the calling thread has used: a cost that a loaded machine does not
// inflate, unlike the time it took.
int64_t thread_cpu_ns();

}  // namespace depthfuse
