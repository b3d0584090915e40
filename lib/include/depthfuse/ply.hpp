// Binary little-endian PLY for fused clouds: positions, normals, colour (optional), and the
// per-point merge count and uncertainty as extra properties. Streaming, so exports stay bounded.
#pragma once

#include <cstdio>
#include <memory>
#include <string>

#include "depthfuse/point_arrays.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse {

struct PlyOptions {
  bool with_color = true;
  bool with_fusion_stats = true;  // merges (uchar saturating... uint16), violations, uncertainty_m
};

class PlyWriter {
 public:
  PlyWriter() = default;
  ~PlyWriter();
  PlyWriter(const PlyWriter&) = delete;
  PlyWriter& operator=(const PlyWriter&) = delete;

  // The vertex count goes in the header, so it must be known up front (export counts first).
  Status open(const std::string& path, const PlyOptions& options, size_t vertex_count);
  // Appends the points of `points` whose keep[i] is non-zero (keep may be null for all).
  Status write(const PointArrays& points, const std::vector<uint8_t>* keep = nullptr);
  // Fails if fewer or more points were written than announced.
  Status close();

 private:
  std::FILE* file_ = nullptr;
  std::string path_;
  PlyOptions options_;
  size_t announced_ = 0, written_ = 0;
};

Status write_ply(const std::string& path, const PointArrays& points, const PlyOptions& options = {});

// Reads a PLY written by depthfuse or any binary/ASCII PLY with x y z (normals, colour optional).
Result<PointArrays> read_ply(const std::string& path);

}  // namespace depthfuse
