#include "depthfuse/store/pcd_writer.hpp"

#include <cerrno>
#include <cstring>
#include <sstream>

namespace depthfuse::store {

namespace {
template <typename T>
inline void put(char*& p, T v) {
  std::memcpy(p, &v, sizeof(T));
  p += sizeof(T);
}
std::string errno_text() { return std::strerror(errno); }
}  // namespace

PcdWriter::~PcdWriter() {
  if (file_) std::fclose(file_);
}

Status PcdWriter::open(const std::string& path, const PcdOptions& options, size_t point_count) {
  if (file_) return internal_error("PcdWriter already open");
  file_ = std::fopen(path.c_str(), "wb");
  if (!file_) return io_error("cannot create " + path + ": " + errno_text());
  path_ = path;
  options_ = options;
  announced_ = point_count;
  written_ = 0;
  std::string fields = "x y z normal_x normal_y normal_z", size = "4 4 4 4 4 4",
              type = "F F F F F F", count = "1 1 1 1 1 1";
  if (options.with_color) {
    fields += " rgb"; size += " 4"; type += " F"; count += " 1";
  }
  if (options.with_fusion_stats) {
    fields += " merges violations uncertainty_m"; size += " 2 2 4"; type += " U U F";
    count += " 1 1 1";
  }
  std::ostringstream h;
  h << "# .PCD v0.7 - Point Cloud Data file format (written by depthfuse)\n"
    << "VERSION 0.7\n"
    << "FIELDS " << fields << "\nSIZE " << size << "\nTYPE " << type << "\nCOUNT " << count << "\n"
    << "WIDTH " << point_count << "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
    << "POINTS " << point_count << "\nDATA binary\n";
  const std::string header = h.str();
  if (std::fwrite(header.data(), 1, header.size(), file_) != header.size())
    return io_error("cannot write " + path + ": " + errno_text());
  return Status::ok();
}

Status PcdWriter::write(const PointArrays& a, const std::vector<uint8_t>* keep) {
  if (!file_) return internal_error("PcdWriter not open");
  const size_t stride = 24 + (options_.with_color ? 4 : 0) + (options_.with_fusion_stats ? 8 : 0);
  constexpr size_t kBatch = 4096;
  buffer_.resize(kBatch * stride);
  size_t i = 0;
  while (i < a.size()) {
    char* p = buffer_.data();
    size_t in_batch = 0;
    for (; i < a.size() && in_batch < kBatch; ++i) {
      if (keep && !(*keep)[i]) continue;
      put(p, a.position_m[i].x()); put(p, a.position_m[i].y()); put(p, a.position_m[i].z());
      put(p, a.state[i].nx); put(p, a.state[i].ny); put(p, a.state[i].nz);
      if (options_.with_color) {
        // PCL packs colour as 0x00RRGGBB in the bytes of a float.
        const uint32_t rgb = (static_cast<uint32_t>(a.state[i].r) << 16) |
                             (static_cast<uint32_t>(a.state[i].g) << 8) | a.state[i].b;
        put(p, rgb);
      }
      if (options_.with_fusion_stats) {
        put(p, a.state[i].merges); put(p, a.state[i].violations); put(p, uncertainty_m(a, i));
      }
      ++in_batch;
    }
    const size_t bytes = in_batch * stride;
    if (std::fwrite(buffer_.data(), 1, bytes, file_) != bytes)
      return io_error("cannot write " + path_ + ": " + errno_text());
    written_ += in_batch;
  }
  return Status::ok();
}

Status PcdWriter::close() {
  if (!file_) return internal_error("PcdWriter not open");
  const bool flushed = std::fflush(file_) == 0;
  const bool closed = std::fclose(file_) == 0;
  file_ = nullptr;
  if (!flushed || !closed) return io_error("cannot finish " + path_ + ": " + errno_text());
  if (written_ != announced_)
    return internal_error(path_ + ": announced " + std::to_string(announced_) +
                          " points but wrote " + std::to_string(written_));
  return Status::ok();
}

}  // namespace depthfuse::store
