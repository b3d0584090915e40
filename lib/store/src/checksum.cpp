// CRC-32 for the blob checks, from libdeflate: Debian's well-kept implementation, which uses the
// CPU's carry-less multiply where it has one. Every checkpoint computes it over every column of
// every chunk it writes, and our own table-driven loop cost more than the chunks' compression.
#include "depthfuse/store/checksum.hpp"

#include <libdeflate.h>

namespace depthfuse::store {

uint32_t crc32(const void* data, size_t size, uint32_t crc) {
  // libdeflate, like zlib, returns 0 for a null buffer instead of continuing the sum.
  if (size == 0) return crc;
  return libdeflate_crc32(crc, data, size);
}

}  // namespace depthfuse::store
