// PLY files of fused clouds: writing through the one point-cloud writer (point_cloud_writer.hpp),
// and a reader for depthfuse's own files and other binary/ASCII PLYs.
#pragma once

#include <string>

#include "depthfuse/point_arrays.hpp"
#include "depthfuse/point_cloud_writer.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse {

// The optional fields of a PLY: colour, and the merge count, violations and uncertainty.
using PlyOptions = CloudFields;

Status write_ply(const std::string& path, const PointArrays& points, const PlyOptions& options = {});

// Reads a PLY written by depthfuse or any binary/ASCII PLY with x y z (normals, colour optional).
Result<PointArrays> read_ply(const std::string& path);

}  // namespace depthfuse
