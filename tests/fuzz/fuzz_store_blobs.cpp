// The blobs of a scan file (a file may come from anywhere, or be damaged on disk), into every blob
// decoder of the store: never a crash, never an allocation the blob's bytes do not justify. The
// first input byte picks the decoder, the rest is the blob.
#include <cstddef>
#include <cstdint>

#include "depthfuse/store/blob_codec.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace depthfuse;
  if (size < 1) return 0;
  static store::BlobCodec codec(1);
  const uint8_t which = data[0] % 4;
  ++data;
  --size;
  switch (which) {
    case 0: {
      PointArrays points;
      (void)codec.decode_points(data, size, "fuzz", &points);
      break;
    }
    case 1: {
      DepthImage depth;
      (void)codec.decode_depth(data, size, "fuzz", &depth);
      break;
    }
    case 2: {
      ColorImage color;
      (void)codec.decode_color(data, size, "fuzz", &color);
      break;
    }
    default: {
      Pose pose;
      (void)store::decode_pose(data, size, "fuzz", &pose);
      break;
    }
  }
  return 0;
}
