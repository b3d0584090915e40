// Binary PCD (PCL's Point Cloud Data format, v0.7) for fused clouds, streaming like PlyWriter:
// open with the point count, write chunk by chunk, close. Fields: x y z normal_x normal_y normal_z
// rgb (PCL's float-packed 0x00RRGGBB) and, optionally, merges violations (uint16) uncertainty_m.
#pragma once

#include <cstdio>
#include <string>
#include <vector>

#include "depthfuse/point_arrays.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse::store {

struct PcdOptions {
  bool with_color = true;
  bool with_fusion_stats = true;
};

class PcdWriter {
 public:
  PcdWriter() = default;
  ~PcdWriter();
  PcdWriter(const PcdWriter&) = delete;
  PcdWriter& operator=(const PcdWriter&) = delete;

  Status open(const std::string& path, const PcdOptions& options, size_t point_count);
  // Appends the points whose keep[i] is non-zero (keep may be null for all).
  Status write(const PointArrays& points, const std::vector<uint8_t>* keep = nullptr);
  // Fails if fewer or more points were written than announced.
  Status close();

 private:
  std::FILE* file_ = nullptr;
  std::string path_;
  PcdOptions options_;
  size_t announced_ = 0, written_ = 0;
  std::vector<char> buffer_;
};

}  // namespace depthfuse::store
