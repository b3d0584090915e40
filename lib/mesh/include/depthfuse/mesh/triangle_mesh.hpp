// A triangle mesh as structure-of-arrays, and its PLY file (binary little-endian: vertex x y z
// [red green blue], face vertex_indices as a uchar-counted list of int), which MeshLab, Open3D, PCL
// and `depthfuse eval` (the vertices) read.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "depthfuse/status.hpp"

namespace depthfuse::mesh {

struct TriangleMesh {
  std::vector<Eigen::Vector3f> vertex_m;            // world frame
  std::vector<std::array<uint8_t, 3>> vertex_rgb;   // empty, or one colour per vertex
  std::vector<std::array<uint32_t, 3>> triangles;   // indices into vertex_m, counter-clockwise

  bool has_color() const { return !vertex_rgb.empty(); }
};

// On failure the partly written file is removed.
Status write_mesh_ply(const std::string& path, const TriangleMesh& mesh);

}  // namespace depthfuse::mesh
