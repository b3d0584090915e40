// What the kernel says about this machine's memory, for checks that refuse work before it runs out.
#pragma once

#include <cstdint>

namespace depthfuse {

// The memory available for new work now (MemAvailable in /proc/meminfo), in bytes; 0 when unknown.
uint64_t available_memory_bytes();

}  // namespace depthfuse
