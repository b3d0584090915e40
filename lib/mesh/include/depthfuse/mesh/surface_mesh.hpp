// A triangle mesh from a fused cloud's oriented points: PCL's Poisson surface reconstruction, then
// trimmed to what the points support. Poisson closes every surface it is given (the open side of a
// corner gets a lid), so a vertex farther from the nearest input point than a few local point
// spacings is dropped with its triangles. PCL stays behind this header: its surface headers cost
// ~1 GB and 20 s per translation unit.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>

#include "depthfuse/mesh/triangle_mesh.hpp"
#include "depthfuse/point_arrays.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse::mesh {

struct MeshOptions {
  // Poisson's octree depth: the finest cell is 1.1 x the cloud's largest extent / 2^depth (10 on a
  // 3 m scene: 3.2 mm). Each step up quadruples the cells on a surface, and the memory with them.
  int depth = 10;
  // A vertex is kept when an input point lies within trim_factor x max(that point's spacing to its
  // neighbours, the finest cell).
  double trim_factor = 2.0;
  bool with_color = true;             // vertex colour from the nearest point, when the cloud has any
  // Refuse (with the estimate and the depth that would fit) when the estimate exceeds this.
  // Unset: the memory the kernel reports as available (MemAvailable).
  std::optional<size_t> memory_budget_bytes;
};

inline constexpr int kMinDepth = 5, kMaxDepth = 14;

struct MemoryEstimate {
  size_t bytes = 0;                   // peak, the input cloud's copies and Poisson's octree
  double cell_m = 0.0;                // the finest Poisson cell
  size_t occupied_cells = 0;          // finest cells holding at least one point
};

// What meshing `points` at `depth` needs, from the points and the octree cells holding them on
// every level (one sort of the finest cells' Morton keys).
MemoryEstimate estimate_memory(const PointArrays& points, int depth);

struct MeshReport {
  size_t input_points = 0;
  MemoryEstimate estimate;
  size_t poisson_vertices = 0, poisson_triangles = 0;
  size_t trimmed_triangles = 0;       // Poisson's triangles the points do not support
};

// Points whose normals are zero or not finite are left out. Fails with a clear message (and no
// attempt) on fewer than 100 usable points or an estimate over the budget.
Result<TriangleMesh> mesh_points(const PointArrays& points, const MeshOptions& options,
                                 MeshReport* report = nullptr);

}  // namespace depthfuse::mesh
