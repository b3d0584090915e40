#include "depthfuse/base/heap_reserve.hpp"

#include <malloc.h>
#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <vector>

namespace depthfuse {

namespace {

// glibc's largest mmap threshold: blocks below it come from the heap, the rest are mapped alone
// and unmapped again when freed.
constexpr size_t kMmapThreshold = size_t{32} << 20;
// The pieces the reserve is taken in: below the threshold, so that they come from the heap.
constexpr size_t kPiece = size_t{16} << 20;

}  // namespace

size_t reserve_heap(size_t bytes) {
  (void)mallopt(M_ARENA_MAX, 1);
  (void)mallopt(M_MMAP_THRESHOLD, static_cast<int>(kMmapThreshold));
  // Never give the heap's top back: the next scan reuses it.
  (void)mallopt(M_TRIM_THRESHOLD, INT32_MAX);
  const size_t page = static_cast<size_t>(sysconf(_SC_PAGESIZE) > 0 ? sysconf(_SC_PAGESIZE) : 4096);
  std::vector<void*> pieces;
  pieces.reserve(bytes / kPiece + 1);
  size_t touched = 0;
  while (touched < bytes) {
    void* p = std::malloc(kPiece);
    if (!p) break;
    pieces.push_back(p);
    // Through a volatile pointer: a compiler may drop writes to memory that is freed unread.
    for (size_t o = 0; o < kPiece; o += page) static_cast<volatile char*>(p)[o] = 0;
    touched += kPiece;
  }
  for (void* p : pieces) std::free(p);
  return touched;
}

}  // namespace depthfuse
