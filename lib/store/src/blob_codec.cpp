// The blob encodings of the scan file (chunk points, keyframe depth and colour, poses): checked,
// compressed, lossless. A codec owns its zstd contexts and scratch buffers and runs on the thread
// that owns its ScanStore (the fusion daemon's worker thread, or a CLI reader).
#include "depthfuse/store/blob_codec.hpp"

#include <zstd.h>

#include <algorithm>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <type_traits>
#include <iterator>
#include <cstddef>

#include "depthfuse/base/delta16.hpp"
#include "depthfuse/store/checksum.hpp"

namespace depthfuse::store {

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__,
              "the scan file stores raw little-endian column bytes");

namespace {

constexpr char kMagic[4] = {'D', 'F', 'B', '1'};
// The header's fields by byte offset (docs/checkpoint-format.md, "Blob encoding"), the column
// table's entries, and the header's CRC after the table.
namespace header {
constexpr size_t kMagic = 0;            // 4 bytes
constexpr size_t kKind = 4;             // u8 BlobKind
constexpr size_t kColumnCount = 5;      // u8
constexpr size_t kReserved = 6;         // u16, 0
constexpr size_t kElementCount = 8;     // u32
constexpr size_t kWidth = 12;           // u32 (images)
constexpr size_t kHeight = 16;          // u32 (images)
constexpr size_t kRawBytes = 20;        // u32
constexpr size_t kCompressedBytes = 24; // u32
constexpr size_t kColumnTable = 28;     // column_count entries
constexpr size_t kCrcBytes = 4;         // u32 CRC-32 of everything before it
// Bytes of a header with `columns` entries, its CRC included.
constexpr size_t size(size_t columns);
}  // namespace header
namespace column_entry {
constexpr size_t kId = 0;               // u8
constexpr size_t kElementSize = 1;      // u8
constexpr size_t kTransform = 2;        // u8 Transform
constexpr size_t kReserved = 3;         // u8, 0
constexpr size_t kCrc = 4;              // u32 CRC-32 of the column's raw bytes
constexpr size_t kSize = 8;
}  // namespace column_entry
constexpr size_t header::size(size_t columns) {
  return kColumnTable + columns * column_entry::kSize + kCrcBytes;
}

enum Transform : uint8_t { kNone = 0, kBytePlanes = 1, kDelta16Planes = 2 };

// Transform 2 runs through the whole column, without zigzag (lib/lcm's wire format predicts each
// row on its own and zigzags: the same transform, other parameters).
Delta16Layout whole_image(size_t count) { return Delta16Layout{count, false}; }

template <typename T>
void put(uint8_t* p, T v) { std::memcpy(p, &v, sizeof(T)); }
template <typename T>
T get(const uint8_t* p) { T v; std::memcpy(&v, p, sizeof(T)); return v; }

std::string hex32(uint32_t v) {
  char buf[16];
  std::snprintf(buf, sizeof(buf), "0x%08" PRIx32, v);
  return buf;
}

// Splits n elements of k bytes into k planes (all first bytes, then all second bytes, ...): float
// exponents and high bytes line up, which zstd compresses far better.
void to_planes(const uint8_t* in, size_t n, size_t k, uint8_t* out) {
  for (size_t p = 0; p < k; ++p) {
    uint8_t* o = out + p * n;
    const uint8_t* s = in + p;
    for (size_t i = 0; i < n; ++i) o[i] = s[i * k];
  }
}

void from_planes(const uint8_t* in, size_t n, size_t k, uint8_t* out) {
  for (size_t p = 0; p < k; ++p) {
    const uint8_t* s = in + p * n;
    uint8_t* o = out + p;
    for (size_t i = 0; i < n; ++i) o[i * k] = s[i];
  }
}

const char* kind_name(BlobKind k) {
  switch (k) {
    case BlobKind::kPoints: return "points";
    case BlobKind::kDepth: return "depth";
    case BlobKind::kColor: return "color";
    case BlobKind::kKeyframeCloud: return "keyframe cloud";
    case BlobKind::kGraph: return "pose graph";
  }
  return "unknown";
}

// The point columns in blob order (ids are positions in this list), and where each field lives in
// PointArrays: the file keeps one column per field, whatever the in-memory layout.
struct PointColumn {
  const char* name;
  uint8_t size;     // bytes per element
  bool in_state;    // PointArrays::state, else PointArrays::position_m
  uint8_t offset;   // byte offset of the field in its record
};
constexpr PointColumn kPointColumns[] = {
    {"x", 4, false, 0}, {"y", 4, false, 4}, {"z", 4, false, 8},
    {"nx", 4, true, offsetof(PointState, nx)},
    {"ny", 4, true, offsetof(PointState, ny)},
    {"nz", 4, true, offsetof(PointState, nz)},
    {"info_xx", 4, true, offsetof(PointState, info_xx)},
    {"info_xy", 4, true, offsetof(PointState, info_xy)},
    {"info_xz", 4, true, offsetof(PointState, info_xz)},
    {"info_yy", 4, true, offsetof(PointState, info_yy)},
    {"info_yz", 4, true, offsetof(PointState, info_yz)},
    {"info_zz", 4, true, offsetof(PointState, info_zz)},
    {"r", 1, true, offsetof(PointState, r)},
    {"g", 1, true, offsetof(PointState, g)},
    {"b", 1, true, offsetof(PointState, b)},
    {"merges", 2, true, offsetof(PointState, merges)},
    {"violations", 2, true, offsetof(PointState, violations)},
    {"last_frame", 4, true, offsetof(PointState, last_frame)},
};
constexpr size_t point_column_bytes() {
  size_t n = 0;
  for (const PointColumn& c : kPointColumns) n += c.size;
  return n;
}
constexpr size_t kPointColumnBytes = point_column_bytes();  // bytes per point in a blob
static_assert(sizeof(Eigen::Vector3f) == 12, "positions are three packed floats");

// Base address and record stride of a column's field in `a`.
template <typename A>
auto column_base(A& a, const PointColumn& c, size_t* stride) {
  using Byte = std::conditional_t<std::is_const_v<A>, const uint8_t, uint8_t>;
  if (c.in_state) {
    *stride = sizeof(PointState);
    return reinterpret_cast<Byte*>(a.state.data()) + c.offset;
  }
  *stride = sizeof(Eigen::Vector3f);
  return reinterpret_cast<Byte*>(a.position_m.data()) + c.offset;
}

struct DepthCodeInfo {
  DepthFormat format;
  float scale;    // units per metre
  bool multiply;  // depth = v * (1/scale) as float, else v / scale
};
constexpr DepthCodeInfo kU16Formats[] = {
    {DepthFormat::kU16DivBy1000, 1000.0f, false},
    {DepthFormat::kU16Times1e3, 1000.0f, true},
    {DepthFormat::kU16DivBy5000, 5000.0f, false},
    {DepthFormat::kU16Times2e4, 5000.0f, true},
};

inline float u16_to_depth(uint16_t v, const DepthCodeInfo& f) {
  return f.multiply ? static_cast<float>(v) * (1.0f / f.scale) : static_cast<float>(v) / f.scale;
}

bool try_u16(const DepthImage& d, const DepthCodeInfo& f, std::vector<uint16_t>* out) {
  out->resize(d.depth_m.size());
  const float* in = d.depth_m.data();
  uint16_t* o = out->data();
  // Blocks without an early exit inside, so that the compiler vectorises the conversion and the
  // bit-exact check (this runs on every logged frame); a block that fails ends the try.
  constexpr size_t kBlock = 256;
  for (size_t begin = 0; begin < d.depth_m.size(); begin += kBlock) {
    const size_t end = std::min(d.depth_m.size(), begin + kBlock);
    uint32_t bad = 0;
    for (size_t i = begin; i < end; ++i) {
      const float m = in[i];
      // Rounded by truncating x + 0.5 (x >= 0), not std::nearbyint, which is a libm call per pixel
      // without SSE4.1; a tie cannot round-trip either way, and the check below is what counts.
      const double units = static_cast<double>(m) * f.scale + 0.5;
      // Out of range (or NaN) becomes a value whose round trip cannot match.
      const bool in_range = units >= 0.0 && units < 65536.0;
      const auto v = static_cast<uint16_t>(static_cast<int32_t>(in_range ? units : 0.0));
      const float back = u16_to_depth(v, f);
      uint32_t back_bits, m_bits;
      std::memcpy(&back_bits, &back, sizeof(float));
      std::memcpy(&m_bits, &m, sizeof(float));
      bad |= static_cast<uint32_t>(!in_range) | (back_bits ^ m_bits);  // must be bit-exact
      o[i] = v;
    }
    if (bad != 0) return false;
  }
  return true;
}

}  // namespace

const char* to_string(DepthFormat f) {
  switch (f) {
    case DepthFormat::kFloat32: return "float32 m";
    case DepthFormat::kU16DivBy1000: return "uint16 mm (/1000)";
    case DepthFormat::kU16Times1e3: return "uint16 mm (*0.001)";
    case DepthFormat::kU16DivBy5000: return "uint16 1/5000 m (/5000)";
    case DepthFormat::kU16Times2e4: return "uint16 1/5000 m (*0.0002)";
  }
  return "unknown";
}

BlobCodec::BlobCodec(int compression_level, std::optional<int> color_compression_level)
    : level_(compression_level),
      color_level_(color_compression_level.value_or(compression_level)),
      cctx_(ZSTD_createCCtx()),
      dctx_(ZSTD_createDCtx()) {}

BlobCodec::~BlobCodec() {
  ZSTD_freeCCtx(cctx_);
  ZSTD_freeDCtx(dctx_);
}

Result<BlobHeader> BlobCodec::read_header(const void* blob, size_t size, const std::string& what) {
  const auto* p = static_cast<const uint8_t*>(blob);
  if (size < header::size(0))
    return corrupt(what + ": blob too short for a header (" + std::to_string(size) + " bytes)");
  if (std::memcmp(p + header::kMagic, kMagic, 4) != 0)
    return corrupt(what + ": not a depthfuse blob (bad magic)");
  const size_t columns = p[header::kColumnCount];
  const size_t header_bytes = header::size(columns);
  if (size < header_bytes)
    return corrupt(what + ": blob truncated inside its header (" + std::to_string(size) + " of " +
                   std::to_string(header_bytes) + " bytes)");
  const uint32_t stored = get<uint32_t>(p + header_bytes - header::kCrcBytes);
  const uint32_t computed = crc32(p, header_bytes - header::kCrcBytes);
  if (stored != computed)
    return corrupt(what + ": blob header checksum mismatch (stored " + hex32(stored) +
                   ", computed " + hex32(computed) + ")");
  BlobHeader h;
  h.kind = static_cast<BlobKind>(p[header::kKind]);
  h.element_count = get<uint32_t>(p + header::kElementCount);
  h.width = get<uint32_t>(p + header::kWidth);
  h.height = get<uint32_t>(p + header::kHeight);
  h.raw_bytes = get<uint32_t>(p + header::kRawBytes);
  h.compressed_bytes = get<uint32_t>(p + header::kCompressedBytes);
  h.first_column_id = columns > 0 ? p[header::kColumnTable + column_entry::kId] : 0;
  if (size != header_bytes + h.compressed_bytes)
    return corrupt(what + ": blob is " + std::to_string(size) + " bytes, its header announces " +
                   std::to_string(header_bytes + h.compressed_bytes) +
                   (size < header_bytes + h.compressed_bytes ? " (truncated)" : ""));
  return h;
}

Status BlobCodec::encode(BlobKind kind, uint32_t count, uint32_t width, uint32_t height,
                         const std::vector<Column>& columns, std::vector<uint8_t>* blob,
                         int level) {
  if (!cctx_ || !dctx_) return internal_error("zstd contexts could not be created");
  size_t raw_bytes = 0;
  for (const Column& c : columns) raw_bytes += static_cast<size_t>(count) * c.element_size;
  if (raw_bytes > UINT32_MAX) return invalid_argument("blob too large: " + std::to_string(raw_bytes));
  raw_.resize(raw_bytes);
  const size_t header_bytes = header::size(columns.size());
  // Built in a reused buffer, then copied out at its final size: resizing the caller's blob to
  // the compression bound zero-filled (and, for a fresh blob, faulted in) the whole bound.
  const size_t bound = header_bytes + ZSTD_compressBound(raw_bytes);
  if (out_.size() < bound) out_.resize(bound);
  uint8_t* h = out_.data();
  std::memcpy(h + header::kMagic, kMagic, 4);
  h[header::kKind] = static_cast<uint8_t>(kind);
  h[header::kColumnCount] = static_cast<uint8_t>(columns.size());
  put<uint16_t>(h + header::kReserved, 0);
  put<uint32_t>(h + header::kElementCount, count);
  put<uint32_t>(h + header::kWidth, width);
  put<uint32_t>(h + header::kHeight, height);
  put<uint32_t>(h + header::kRawBytes, static_cast<uint32_t>(raw_bytes));

  size_t offset = 0;
  for (size_t ci = 0; ci < columns.size(); ++ci) {
    const Column& c = columns[ci];
    const size_t bytes = static_cast<size_t>(count) * c.element_size;
    const auto* src = static_cast<const uint8_t*>(c.data);
    uint8_t* e = h + header::kColumnTable + ci * column_entry::kSize;
    e[column_entry::kId] = c.id;
    e[column_entry::kElementSize] = c.element_size;
    e[column_entry::kTransform] = c.transform;
    e[column_entry::kReserved] = 0;
    put<uint32_t>(e + column_entry::kCrc, bytes ? crc32(src, bytes) : crc32(nullptr, 0));
    uint8_t* dst = raw_.data() + offset;
    if (c.transform == kBytePlanes && c.element_size > 1) {
      to_planes(src, count, c.element_size, dst);
    } else if (c.transform == kDelta16Planes) {
      // Difference to the previous element (wrapping), then planes: smooth depth becomes small.
      delta16_to_planes(static_cast<const uint16_t*>(c.data), count, whole_image(count), dst);
    } else if (bytes) {
      std::memcpy(dst, src, bytes);
    }
    offset += bytes;
  }
  const size_t z = ZSTD_compressCCtx(cctx_, out_.data() + header_bytes, bound - header_bytes,
                                     raw_.data(), raw_bytes, level);
  if (ZSTD_isError(z)) return internal_error(std::string("zstd compression failed: ") +
                                             ZSTD_getErrorName(z));
  h = out_.data();
  put<uint32_t>(h + header::kCompressedBytes, static_cast<uint32_t>(z));
  put<uint32_t>(h + header_bytes - header::kCrcBytes, crc32(h, header_bytes - header::kCrcBytes));
  blob->assign(out_.data(), out_.data() + header_bytes + z);
  return Status::ok();
}

// `size` was validated against the header by read_header.
Status BlobCodec::decode(const void* blob, size_t /*size*/, const std::string& what, BlobKind kind,
                         const BlobHeader& header, std::vector<Column>& columns) {
  if (!cctx_ || !dctx_) return internal_error("zstd contexts could not be created");
  const auto* p = static_cast<const uint8_t*>(blob);
  if (header.kind != kind)
    return corrupt(what + ": expected a " + kind_name(kind) + " blob, found kind " +
                   std::to_string(static_cast<int>(header.kind)));
  if (p[header::kColumnCount] != columns.size())
    return corrupt(what + ": " + std::to_string(p[header::kColumnCount]) + " columns, expected " +
                   std::to_string(columns.size()));
  const size_t count = header.element_count;
  size_t raw_bytes = 0;
  for (size_t ci = 0; ci < columns.size(); ++ci) {
    const uint8_t* e = p + header::kColumnTable + ci * column_entry::kSize;
    const uint8_t id = e[column_entry::kId], element_size = e[column_entry::kElementSize];
    if (id != columns[ci].id || element_size != columns[ci].element_size ||
        e[column_entry::kTransform] > kDelta16Planes)
      return corrupt(what + ": column " + std::to_string(ci) + " has id " + std::to_string(id) +
                     " size " + std::to_string(element_size) + ", expected '" + columns[ci].name + "'");
    columns[ci].transform = e[column_entry::kTransform];
    raw_bytes += count * columns[ci].element_size;
  }
  if (raw_bytes != header.raw_bytes)
    return corrupt(what + ": header sizes disagree (" + std::to_string(count) + " elements but " +
                   std::to_string(header.raw_bytes) + " raw bytes)");
  const size_t header_bytes = header::size(columns.size());
  raw_.resize(raw_bytes);
  const size_t n = ZSTD_decompressDCtx(dctx_, raw_.data(), raw_bytes, p + header_bytes,
                                       header.compressed_bytes);
  if (ZSTD_isError(n))
    return corrupt(what + ": compressed payload is damaged (zstd: " + ZSTD_getErrorName(n) + ")");
  if (n != raw_bytes)
    return corrupt(what + ": payload decompressed to " + std::to_string(n) + " bytes, expected " +
                   std::to_string(raw_bytes));
  size_t offset = 0;
  for (size_t ci = 0; ci < columns.size(); ++ci) {
    Column& c = columns[ci];
    const size_t bytes = count * c.element_size;
    const uint8_t* src = raw_.data() + offset;
    auto* dst = static_cast<uint8_t*>(c.out);
    if (c.transform == kBytePlanes && c.element_size > 1) {
      from_planes(src, count, c.element_size, dst);
    } else if (c.transform == kDelta16Planes) {
      if (c.element_size != 2) return corrupt(what + ": delta transform on a non-16-bit column");
      delta16_from_planes(src, count, whole_image(count), static_cast<uint16_t*>(c.out));
    } else if (bytes) {
      std::memcpy(dst, src, bytes);
    }
    const uint32_t stored =
        get<uint32_t>(p + header::kColumnTable + ci * column_entry::kSize + column_entry::kCrc);
    const uint32_t computed = crc32(dst, bytes);
    if (stored != computed)
      return corrupt(what + ": column '" + c.name + "' checksum mismatch (stored " + hex32(stored) +
                     ", computed " + hex32(computed) + ")");
    offset += bytes;
  }
  return Status::ok();
}

Status BlobCodec::encode_points(const PointArrays& a, std::vector<uint8_t>* blob) {
  const size_t n = a.size();
  if (n > UINT32_MAX) return invalid_argument("chunk has too many points");
  if (a.state.size() != n) return invalid_argument("PointArrays columns have different lengths");
  // Gather each field into a contiguous column.
  columns_.resize(n * kPointColumnBytes);
  std::vector<Column> cols;
  cols.reserve(std::size(kPointColumns));
  uint8_t* dst = columns_.data();
  uint8_t id = 0;
  for (const PointColumn& c : kPointColumns) {
    size_t stride = 0;
    const uint8_t* src = n ? column_base(a, c, &stride) : nullptr;
    for (size_t i = 0; i < n; ++i) std::memcpy(dst + i * c.size, src + i * stride, c.size);
    cols.push_back({id++, c.size, static_cast<uint8_t>(c.size > 1 ? kBytePlanes : kNone), dst,
                    nullptr, c.name});
    dst += n * c.size;
  }
  return encode(BlobKind::kPoints, static_cast<uint32_t>(n), 0, 0, cols, blob, level_);
}

Status BlobCodec::decode_points(const void* blob, size_t size, const std::string& what,
                                PointArrays* out) {
  auto header = read_header(blob, size, what);
  if (!header) return header.status();
  if (header->kind != BlobKind::kPoints)
    return corrupt(what + ": expected a points blob, found kind " +
                   std::to_string(static_cast<int>(header->kind)));
  const size_t n = header->element_count;
  // Size check before allocating: a damaged count must not become a huge allocation.
  if (n > static_cast<size_t>(header->raw_bytes) / kPointColumnBytes + 1)
    return corrupt(what + ": header announces " + std::to_string(n) + " points in " +
                   std::to_string(header->raw_bytes) + " bytes");
  columns_.resize(n * kPointColumnBytes);
  std::vector<Column> cols;
  cols.reserve(std::size(kPointColumns));
  uint8_t* dst = columns_.data();
  uint8_t id = 0;
  for (const PointColumn& c : kPointColumns) {
    cols.push_back({id++, c.size, 0, nullptr, dst, c.name});
    dst += n * c.size;
  }
  Status st = decode(blob, size, what, BlobKind::kPoints, *header, cols);
  if (!st) {
    out->clear();
    return st;
  }
  // Scatter the columns into the records.
  out->resize(n);
  const uint8_t* src = columns_.data();
  for (const PointColumn& c : kPointColumns) {
    size_t stride = 0;
    uint8_t* base = n ? column_base(*out, c, &stride) : nullptr;
    for (size_t i = 0; i < n; ++i) std::memcpy(base + i * stride, src + i * c.size, c.size);
    src += n * c.size;
  }
  return st;
}

Status BlobCodec::encode_column(BlobKind kind, const void* data, uint32_t count,
                                uint8_t element_size, std::vector<uint8_t>* blob) {
  const std::vector<Column> cols = {
      {0, element_size, static_cast<uint8_t>(element_size > 1 ? kBytePlanes : kNone), data, nullptr,
       "values"}};
  return encode(kind, count, 0, 0, cols, blob, level_);
}

Status BlobCodec::decode_column(const void* blob, size_t size, const std::string& what,
                                BlobKind kind, uint8_t element_size, std::vector<uint8_t>* out) {
  auto header = read_header(blob, size, what);
  if (!header) return header.status();
  const size_t n = header->element_count;
  // Size check before allocating: a damaged count must not become a huge allocation.
  if (element_size == 0 || n * element_size != header->raw_bytes)
    return corrupt(what + ": header announces " + std::to_string(n) + " elements in " +
                   std::to_string(header->raw_bytes) + " bytes");
  out->resize(n * element_size);
  std::vector<Column> cols = {{0, element_size, 0, nullptr, out->data(), "values"}};
  Status st = decode(blob, size, what, kind, *header, cols);
  if (!st) out->clear();
  return st;
}

Status BlobCodec::encode_depth(const DepthImage& depth, std::vector<uint8_t>* blob,
                               DepthFormat* chosen) {
  if (depth.width <= 0 || depth.height <= 0 ||
      depth.depth_m.size() != static_cast<size_t>(depth.width) * depth.height)
    return invalid_argument("depth image size " + std::to_string(depth.width) + "x" +
                            std::to_string(depth.height) + " does not match its data");
  const auto n = static_cast<uint32_t>(depth.depth_m.size());
  const auto w = static_cast<uint32_t>(depth.width), h = static_cast<uint32_t>(depth.height);
  for (const DepthCodeInfo& f : kU16Formats) {
    if (try_u16(depth, f, &u16_)) {
      if (chosen) *chosen = f.format;
      return encode(BlobKind::kDepth, n, w, h,
                    {{static_cast<uint8_t>(f.format), 2, kDelta16Planes, u16_.data(), nullptr,
                      "depth"}},
                    blob, level_);
    }
  }
  if (chosen) *chosen = DepthFormat::kFloat32;
  return encode(BlobKind::kDepth, n, w, h,
                {{static_cast<uint8_t>(DepthFormat::kFloat32), 4, kBytePlanes,
                  depth.depth_m.data(), nullptr, "depth"}},
                blob, level_);
}

Status BlobCodec::decode_depth(const void* blob, size_t size, const std::string& what,
                               DepthImage* out) {
  auto header = read_header(blob, size, what);
  if (!header) return header.status();
  const BlobHeader& h = *header;
  if (h.kind != BlobKind::kDepth)
    return corrupt(what + ": expected a depth blob, found kind " + std::to_string(static_cast<int>(h.kind)));
  if (static_cast<uint64_t>(h.width) * h.height != h.element_count || h.width == 0 ||
      h.width > 100000 || h.height > 100000)
    return corrupt(what + ": depth size " + std::to_string(h.width) + "x" +
                   std::to_string(h.height) + " disagrees with " +
                   std::to_string(h.element_count) + " pixels");
  const auto format = static_cast<DepthFormat>(h.first_column_id);
  out->width = static_cast<int>(h.width);
  out->height = static_cast<int>(h.height);
  out->depth_m.assign(h.element_count, 0.0f);
  if (format == DepthFormat::kFloat32) {
    std::vector<Column> cols{{0, 4, 0, nullptr, out->depth_m.data(), "depth"}};
    return decode(blob, size, what, BlobKind::kDepth, h, cols);
  }
  for (const DepthCodeInfo& f : kU16Formats) {
    if (f.format != format) continue;
    u16_.resize(h.element_count);
    std::vector<Column> cols{{static_cast<uint8_t>(f.format), 2, 0, nullptr, u16_.data(), "depth"}};
    DF_RETURN_IF_ERROR(decode(blob, size, what, BlobKind::kDepth, h, cols));
    for (size_t i = 0; i < u16_.size(); ++i) out->depth_m[i] = u16_to_depth(u16_[i], f);
    return Status::ok();
  }
  return corrupt(what + ": unknown depth format " + std::to_string(h.first_column_id));
}

Status BlobCodec::encode_color(const ColorImage& color, std::vector<uint8_t>* blob) {
  if (color.width <= 0 || color.height <= 0 ||
      color.rgb.size() != static_cast<size_t>(color.width) * color.height * 3)
    return invalid_argument("colour image size does not match its data");
  const auto n = static_cast<uint32_t>(color.width * color.height);
  return encode(BlobKind::kColor, n, static_cast<uint32_t>(color.width),
                static_cast<uint32_t>(color.height),
                {{0, 3, kBytePlanes, color.rgb.data(), nullptr, "rgb"}}, blob, color_level_);
}

Status BlobCodec::decode_color(const void* blob, size_t size, const std::string& what,
                               ColorImage* out) {
  auto header = read_header(blob, size, what);
  if (!header) return header.status();
  const BlobHeader& h = *header;
  if (h.kind != BlobKind::kColor)
    return corrupt(what + ": expected a colour blob, found kind " + std::to_string(static_cast<int>(h.kind)));
  if (static_cast<uint64_t>(h.width) * h.height != h.element_count || h.width == 0 ||
      h.width > 100000 || h.height > 100000)
    return corrupt(what + ": colour size disagrees with its pixel count");
  out->width = static_cast<int>(h.width);
  out->height = static_cast<int>(h.height);
  out->rgb.assign(static_cast<size_t>(h.element_count) * 3, 0);
  std::vector<Column> cols{{0, 3, 0, nullptr, out->rgb.data(), "rgb"}};
  return decode(blob, size, what, BlobKind::kColor, h, cols);
}

std::vector<uint8_t> encode_pose(const Pose& T) {
  std::vector<uint8_t> out(12 * sizeof(double));
  const Eigen::Matrix4d m = T.matrix();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) put<double>(out.data() + (r * 4 + c) * sizeof(double), m(r, c));
  return out;
}

Status decode_pose(const void* blob, size_t size, const std::string& what, Pose* out) {
  if (!blob || size != 12 * sizeof(double))
    return corrupt(what + ": pose blob is " + std::to_string(size) + " bytes, expected 96");
  const auto* p = static_cast<const uint8_t*>(blob);
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 4; ++c) {
      m(r, c) = get<double>(p + (r * 4 + c) * sizeof(double));
      if (!std::isfinite(m(r, c))) return corrupt(what + ": pose has a non-finite entry");
    }
  }
  const double orthogonality = (m.topLeftCorner<3, 3>().transpose() * m.topLeftCorner<3, 3>() -
                                Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (orthogonality > 1e-6) return corrupt(what + ": pose rotation is not orthonormal");
  out->matrix() = m;
  return Status::ok();
}

uint32_t pose_record_checksum(const PoseFields& f, const void* pose_blob, size_t pose_size) {
  return RowCrc()
      .add(f.frame_id).add(f.utime)
      .bytes(pose_blob, pose_size)
      .add(static_cast<uint8_t>(f.registered ? 1 : 0)).add(f.fitness).add(f.rmse_m)
      .add(f.correspondences)
      .value();
}

}  // namespace depthfuse::store
