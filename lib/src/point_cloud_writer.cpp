#include "depthfuse/point_cloud_writer.hpp"

#include <cstring>
#include <sstream>

#include "depthfuse/base/errno_text.hpp"

namespace depthfuse {

namespace {

template <typename T>
inline void put(char*& p, T v) {
  std::memcpy(p, &v, sizeof(T));
  p += sizeof(T);
}

std::string ply_header(const CloudFields& fields, size_t point_count) {
  std::ostringstream h;
  h << "ply\nformat binary_little_endian 1.0\ncomment written by depthfuse\n"
    << "element vertex " << point_count << "\n"
    << "property float x\nproperty float y\nproperty float z\n"
    << "property float nx\nproperty float ny\nproperty float nz\n";
  if (fields.with_color) h << "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  if (fields.with_fusion_stats)
    h << "property ushort merges\nproperty ushort violations\nproperty float uncertainty_m\n";
  h << "end_header\n";
  return h.str();
}

std::string pcd_header(const CloudFields& fields, size_t point_count) {
  std::string names = "x y z normal_x normal_y normal_z", size = "4 4 4 4 4 4",
              type = "F F F F F F", count = "1 1 1 1 1 1";
  if (fields.with_color) {
    names += " rgb"; size += " 4"; type += " F"; count += " 1";
  }
  if (fields.with_fusion_stats) {
    names += " merges violations uncertainty_m"; size += " 2 2 4"; type += " U U F";
    count += " 1 1 1";
  }
  std::ostringstream h;
  h << "# .PCD v0.7 - Point Cloud Data file format (written by depthfuse)\n"
    << "VERSION 0.7\n"
    << "FIELDS " << names << "\nSIZE " << size << "\nTYPE " << type << "\nCOUNT " << count << "\n"
    << "WIDTH " << point_count << "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
    << "POINTS " << point_count << "\nDATA binary\n";
  return h.str();
}

// Bytes of a point's colour: PLY has three uchar properties, PCD one packed field.
size_t color_bytes(CloudFormat format) { return format == CloudFormat::kPly ? 3 : 4; }

// What a format calls its points, for errors.
const char* point_word(CloudFormat format) {
  return format == CloudFormat::kPly ? "vertices" : "points";
}

}  // namespace

PointCloudWriter::~PointCloudWriter() {
  if (file_) std::fclose(file_);
}

Status PointCloudWriter::open(const std::string& path, CloudFormat format, const CloudFields& fields,
                              size_t point_count) {
  if (file_) return internal_error("PointCloudWriter already open");
  file_ = std::fopen(path.c_str(), "wb");
  if (!file_) return io_error("cannot create " + path + ": " + errno_text());
  path_ = path;
  format_ = format;
  fields_ = fields;
  stride_ = 6 * sizeof(float) + (fields.with_color ? color_bytes(format) : 0) +
            (fields.with_fusion_stats ? 2 * sizeof(uint16_t) + sizeof(float) : 0);
  announced_ = point_count;
  written_ = 0;
  const std::string header =
      format == CloudFormat::kPly ? ply_header(fields, point_count) : pcd_header(fields, point_count);
  if (std::fwrite(header.data(), 1, header.size(), file_) != header.size())
    return io_error("cannot write " + path + ": " + errno_text());
  return Status::ok();
}

Status PointCloudWriter::write(const PointArrays& a, const std::vector<uint8_t>* keep) {
  if (!file_) return internal_error("PointCloudWriter not open");
  constexpr size_t kBlock = 4096;  // points per fwrite
  buffer_.resize(kBlock * stride_);
  const bool packed_rgb = format_ == CloudFormat::kPcd;
  size_t i = 0;
  while (i < a.size()) {
    char* p = buffer_.data();
    size_t in_block = 0;
    for (; i < a.size() && in_block < kBlock; ++i) {
      if (keep && !(*keep)[i]) continue;
      const PointState& s = a.state[i];
      put(p, a.position_m[i].x()); put(p, a.position_m[i].y()); put(p, a.position_m[i].z());
      put(p, s.nx); put(p, s.ny); put(p, s.nz);
      if (fields_.with_color) {
        if (packed_rgb) {
          put(p, (static_cast<uint32_t>(s.r) << 16) | (static_cast<uint32_t>(s.g) << 8) | s.b);
        } else {
          put(p, s.r); put(p, s.g); put(p, s.b);
        }
      }
      if (fields_.with_fusion_stats) {
        put(p, s.merges); put(p, s.violations); put(p, uncertainty_m(a, i));
      }
      ++in_block;
    }
    const size_t bytes = in_block * stride_;
    if (std::fwrite(buffer_.data(), 1, bytes, file_) != bytes)
      return io_error("cannot write " + path_ + ": " + errno_text());
    written_ += in_block;
  }
  return Status::ok();
}

Status PointCloudWriter::finish() {
  if (!file_) return internal_error("PointCloudWriter not open");
  const bool flushed = std::fflush(file_) == 0;
  const bool closed = std::fclose(file_) == 0;
  file_ = nullptr;
  if (!flushed || !closed) return io_error("cannot finish " + path_ + ": " + errno_text());
  if (written_ != announced_)
    return internal_error(path_ + ": announced " + std::to_string(announced_) + " " +
                          point_word(format_) + " but wrote " + std::to_string(written_));
  return Status::ok();
}

Status write_point_cloud(const std::string& path, CloudFormat format, const PointArrays& points,
                         const CloudFields& fields) {
  PointCloudWriter w;
  DF_RETURN_IF_ERROR(w.open(path, format, fields, points.size()));
  DF_RETURN_IF_ERROR(w.write(points));
  return w.finish();
}

}  // namespace depthfuse
