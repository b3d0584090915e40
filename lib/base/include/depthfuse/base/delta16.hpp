// The 16-bit delta transform of depth images, one implementation for the wire (lib/lcm's
// ENCODING_ZSTD_DELTA_UINT16) and the scan file (lib/store's blob transform 2): each value minus
// the one before it in its run (the first of a run minus 0), wrapping, optionally zigzag-mapped,
// split into a plane of the low bytes and then a plane of the high bytes. Smooth depth becomes small
// numbers that zstd compresses far better than the values. The two formats differ only in the
// parameters: the wire predicts each row on its own and zigzags (run = the image's width), the
// scan file runs through the whole image without (run = the pixel count).
#pragma once

#include <cstddef>
#include <cstdint>

namespace depthfuse {

struct Delta16Layout {
  size_t run = 0;       // values per run, > 0; the last run may be shorter
  bool zigzag = false;  // map a signed step s to 2s (s >= 0) or -2s - 1 (s < 0)
};

// `n` values into 2n bytes: the n low bytes, then the n high bytes.
void delta16_to_planes(const uint16_t* values, size_t n, const Delta16Layout& layout,
                       uint8_t* planes);
// The inverse: 2n bytes of planes into `n` values.
void delta16_from_planes(const uint8_t* planes, size_t n, const Delta16Layout& layout,
                         uint16_t* values);

}  // namespace depthfuse
