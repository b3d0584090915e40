// Fused clouds to a file, streaming so that exports stay bounded: open with the point count (it
// goes in the header), write blocks of points, finish. Two binary formats with the same fields:
//  - PLY (binary little-endian): x y z nx ny nz, red green blue (uchar), merges violations
//    (ushort) uncertainty_m;
//  - PCD (PCL's Point Cloud Data v0.7, binary): x y z normal_x normal_y normal_z, rgb (PCL's
//    0x00RRGGBB packed in the bytes of a float), merges violations (uint16) uncertainty_m.
// Colour and the fusion statistics are optional.
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "depthfuse/point_arrays.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse {

enum class CloudFormat { kPly, kPcd };

// Which of the optional fields a cloud file carries.
struct CloudFields {
  bool with_color = true;
  bool with_fusion_stats = true;  // merges, violations, uncertainty_m
};

class PointCloudWriter {
 public:
  PointCloudWriter() = default;
  ~PointCloudWriter();
  PointCloudWriter(const PointCloudWriter&) = delete;
  PointCloudWriter& operator=(const PointCloudWriter&) = delete;

  // Creates the file and writes its header, which holds the point count (export counts first).
  Status open(const std::string& path, CloudFormat format, const CloudFields& fields,
              size_t point_count);
  // Appends the points of `points` whose keep[i] is non-zero (keep may be null for all).
  Status write(const PointArrays& points, const std::vector<uint8_t>* keep = nullptr);
  // Flushes and closes the file; fails if fewer or more points were written than announced.
  Status finish();

 private:
  std::FILE* file_ = nullptr;
  std::string path_;
  CloudFormat format_ = CloudFormat::kPly;
  CloudFields fields_;
  size_t stride_ = 0;                        // bytes per point in the file
  size_t announced_ = 0, written_ = 0;
  std::vector<char> buffer_;                 // one block of points as the file stores them
};

// A whole cloud at once.
Status write_point_cloud(const std::string& path, CloudFormat format, const PointArrays& points,
                         const CloudFields& fields = {});

}  // namespace depthfuse
