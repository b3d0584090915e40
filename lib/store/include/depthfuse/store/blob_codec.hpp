// The blobs of the scan file: a chunk's points, a keyframe's depth and colour, a pose. Each blob is
// self-describing and checked: a header with its own CRC-32, the columns' element sizes and a
// CRC-32 of every column's raw bytes, then one zstd frame. Decoding names what is damaged
// ("column 'nx': checksum mismatch"). Lossless: decode(encode(x)) is bit-identical to x.
// Layout: docs/checkpoint-format.md ("Blob encoding").
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "depthfuse/point_arrays.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

struct ZSTD_CCtx_s;
struct ZSTD_DCtx_s;

namespace depthfuse::store {

// kKeyframeCloud and kGraph: the pose graph's blobs (graph_codec.hpp), one column each.
enum class BlobKind : uint8_t {
  kPoints = 1, kDepth = 2, kColor = 3, kKeyframeCloud = 4, kGraph = 5
};

// How a keyframe's depth is stored. The encoder picks the first uint16 format that reproduces
// every pixel bit for bit (depth from a Kinect or a TUM PNG), and raw float32 otherwise.
enum class DepthFormat : uint8_t {
  kFloat32 = 0,        // IEEE float metres
  kU16DivBy1000 = 1,   // millimetres: depth_m = float(v) / 1000.0f
  kU16Times1e3 = 2,    //              depth_m = float(v) * 0.001f
  kU16DivBy5000 = 3,   // TUM PNG units: depth_m = float(v) / 5000.0f
  kU16Times2e4 = 4,    //              depth_m = float(v) * 0.0002f
};
const char* to_string(DepthFormat f);

// What a blob holds, without decoding the payload (inspect, integrity checks).
struct BlobHeader {
  BlobKind kind = BlobKind::kPoints;
  uint32_t element_count = 0;
  uint32_t width = 0, height = 0;     // images only
  uint32_t raw_bytes = 0, compressed_bytes = 0;
  uint8_t first_column_id = 0;        // for depth: the DepthFormat
};

// Encoder/decoder with reusable zstd contexts and scratch buffers. Not thread-safe; one per thread.
class BlobCodec {
 public:
  // zstd levels; colour has its own (default: the same), since a camera's colour gains little
  // from a slow level and costs most of a frame's encoding at one.
  explicit BlobCodec(int compression_level = 3, std::optional<int> color_compression_level = {});
  ~BlobCodec();
  BlobCodec(const BlobCodec&) = delete;
  BlobCodec& operator=(const BlobCodec&) = delete;

  Status encode_points(const PointArrays& points, std::vector<uint8_t>* blob);
  // `what` names the blob in errors, e.g. "chunk (1,2,-3)".
  Status decode_points(const void* blob, size_t size, const std::string& what, PointArrays* out);

  Status encode_depth(const DepthImage& depth, std::vector<uint8_t>* blob,
                      DepthFormat* chosen = nullptr);
  Status decode_depth(const void* blob, size_t size, const std::string& what, DepthImage* out);

  Status encode_color(const ColorImage& color, std::vector<uint8_t>* blob);
  Status decode_color(const void* blob, size_t size, const std::string& what, ColorImage* out);

  // One column of `count` elements of `element_size` bytes (stored as byte planes when wider than
  // a byte), for blobs whose layout their users define (the pose graph's).
  Status encode_column(BlobKind kind, const void* data, uint32_t count, uint8_t element_size,
                       std::vector<uint8_t>* blob);
  // Its elements into *out (count * element_size bytes); a blob of another kind or element size
  // is an error.
  Status decode_column(const void* blob, size_t size, const std::string& what, BlobKind kind,
                       uint8_t element_size, std::vector<uint8_t>* out);

  // Validates magic, header checksum and sizes (not the payload).
  static Result<BlobHeader> read_header(const void* blob, size_t size, const std::string& what);

 private:
  struct Column {
    uint8_t id;
    uint8_t element_size;
    uint8_t transform;
    const void* data;     // encode: source
    void* out;            // decode: destination (element_count * element_size bytes)
    const char* name;
  };
  Status encode(BlobKind kind, uint32_t count, uint32_t width, uint32_t height,
                const std::vector<Column>& columns, std::vector<uint8_t>* blob, int level);
  // Decodes into columns[i].out after checking the header agrees with `columns` (ids, sizes).
  Status decode(const void* blob, size_t size, const std::string& what, BlobKind kind,
                const BlobHeader& header, std::vector<Column>& columns);

  int level_, color_level_;
  ZSTD_CCtx_s* cctx_ = nullptr;
  ZSTD_DCtx_s* dctx_ = nullptr;
  std::vector<uint8_t> raw_;     // transformed columns, concatenated
  std::vector<uint8_t> out_;     // the blob being encoded
  std::vector<uint16_t> u16_;    // depth scratch
  std::vector<uint8_t> columns_; // point fields gathered into columns
};

// Poses are stored as the top three rows of the 4x4 matrix, 12 little-endian doubles row-major.
std::vector<uint8_t> encode_pose(const Pose& T);
Status decode_pose(const void* blob, size_t size, const std::string& what, Pose* out);

// A row of the poses table but its pose blob, as the checksum covers it.
struct PoseFields {
  uint32_t frame_id = 0;
  int64_t utime = 0;
  bool registered = false;
  double fitness = 0.0, rmse_m = 0.0;
  uint32_t correspondences = 0;
};
// CRC-32 of a pose row (poses.checksum): frame_id u32, utime i64, the pose blob's bytes,
// registered u8, fitness f64, rmse_m f64, correspondences u32, little-endian, in this order.
uint32_t pose_record_checksum(const PoseFields& fields, const void* pose_blob, size_t pose_size);

}  // namespace depthfuse::store
