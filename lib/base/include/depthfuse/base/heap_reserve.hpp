// Memory taken once, at a daemon's start, so that its real-time work never waits for the kernel.
#pragma once

#include <cstddef>

namespace depthfuse {

// Makes the C library's heap keep what it is given back, and gives it `bytes` of memory that is
// already mapped: later allocations of up to 32 MiB reuse it without a page fault. A scan's first
// frames build the map from nothing and fault in about a hundred MiB of new memory; each 4 KiB page
// costs the kernel microseconds, and together they cost several frame periods
// (docs/history/results-sessions-1-33.md, session 31), so frames were dropped at the start of every
// scan. Not with transparent huge pages: where the kernel compacts memory for them on a fault
// (defrag "madvise"), fusion slowed down by half after a quarter of a minute
// (docs/history/results-sessions-1-33.md, session 31).
//
// Call it before the process starts threads: it makes all threads share one heap (with a heap per
// thread, memory freed in one is not reused by another, and a thread's heap is bounded to 64 MiB
// pieces). Best effort: what cannot be set is left as it is. Returns the bytes touched.
size_t reserve_heap(size_t bytes);

}  // namespace depthfuse
