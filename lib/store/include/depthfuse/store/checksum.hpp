// CRC-32 (IEEE 802.3, the polynomial of zlib, PNG and gzip) for the scan file's checks: of blobs
// and their columns, and of rows (RowCrc).
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>

namespace depthfuse::store {

// crc32("123456789") == 0xCBF43926. Pass a previous result as `crc` to continue a running sum.
uint32_t crc32(const void* data, size_t size, uint32_t crc = 0);

// The CRC-32 of a row's values, each appended as its little-endian bytes in the order given, e.g.
// RowCrc().add(frame_id).add(utime).bytes(pose, 96).value(). Every row checksum of the scan file
// (poses, keyframes, checkpoints, the frame log) is built with it; their layouts are in
// docs/checkpoint-format.md.
class RowCrc {
 public:
  template <typename T>
  RowCrc& add(T v) {
    static_assert(std::is_arithmetic_v<T>, "values, not objects");
    uint8_t b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));  // little-endian hosts only (blob_codec.cpp asserts it)
    return bytes(b, sizeof(T));
  }
  RowCrc& bytes(const void* p, size_t n) {
    crc_ = crc32(p, n, crc_);
    return *this;
  }
  uint32_t value() const { return crc_; }

 private:
  uint32_t crc_ = 0;
};

}  // namespace depthfuse::store
