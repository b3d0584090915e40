// CRC-32 (IEEE 802.3, the polynomial of zlib, PNG and gzip) for the scan file's blob checks.
#pragma once

#include <cstddef>
#include <cstdint>

namespace depthfuse::store {

// crc32("123456789") == 0xCBF43926. Pass a previous result as `crc` to continue a running sum.
uint32_t crc32(const void* data, size_t size, uint32_t crc = 0);

}  // namespace depthfuse::store
