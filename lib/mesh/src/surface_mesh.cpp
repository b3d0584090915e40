// Poisson reconstruction (PCL) and trimming. The only translation unit with PCL's surface and search
// headers.
#include "depthfuse/mesh/surface_mesh.hpp"

#include <pcl/point_types.h>
#include <pcl/search/kdtree.h>
#include <pcl/surface/poisson.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "depthfuse/base/meminfo.hpp"

namespace depthfuse::mesh {

namespace {

using Cloud = pcl::PointCloud<pcl::PointNormal>;

// Peak bytes per input point and per octree cell holding a point (summed over the levels), fitted
// from above to export --mesh's peak resident memory on the synthetic corner at depths 9-11
// (docs/history/results-sessions-1-33.md, "Issue 21: mesh").
constexpr double kBytesPerPoint = 1500.0;
constexpr double kBytesPerCell = 700.0;
// Neighbours over which a point's spacing is averaged.
constexpr int kSpacingNeighbours = 6;

bool usable(const Eigen::Vector3f& p, const Eigen::Vector3f& n) {
  return p.allFinite() && n.allFinite() && n.squaredNorm() > 0.25f;
}

Eigen::AlignedBox3f usable_bounds(const PointArrays& points, size_t* count) {
  Eigen::AlignedBox3f box;
  *count = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    if (!usable(points.position(i), points.normal(i))) continue;
    box.extend(points.position(i));
    ++*count;
  }
  return box;
}

double cell_size_m(const Eigen::AlignedBox3f& box, int depth) {
  // Poisson's cube: the bounding box's largest side times its scale (PCL's default, 1.1).
  return 1.1 * static_cast<double>(box.sizes().maxCoeff()) / std::ldexp(1.0, depth);
}

std::string gigabytes(double bytes) {
  char s[32];
  std::snprintf(s, sizeof s, "%.2f GB", bytes / 1e9);
  return s;
}

std::string millimetres(double m) {
  char s[32];
  std::snprintf(s, sizeof s, "%.1f mm", m * 1e3);
  return s;
}

}  // namespace

MemoryEstimate estimate_memory(const PointArrays& points, int depth) {
  MemoryEstimate e;
  size_t n = 0;
  const Eigen::AlignedBox3f box = usable_bounds(points, &n);
  if (n == 0) return e;
  e.cell_m = std::max(cell_size_m(box, depth), 1e-9);
  // Morton keys of the finest cells: a cell's parent is its key >> 3, so one sort serves every level.
  std::vector<uint64_t> keys;
  keys.reserve(n);
  const uint32_t last = (1u << depth) - 1;
  for (size_t i = 0; i < points.size(); ++i) {
    if (!usable(points.position(i), points.normal(i))) continue;
    const Eigen::Vector3f rel = (points.position(i) - box.min()) / static_cast<float>(e.cell_m);
    uint64_t key = 0;
    for (int a = 0; a < 3; ++a) {
      const uint32_t c = std::min(last, static_cast<uint32_t>(std::max(0.0f, rel[a])));
      for (int b = 0; b < depth; ++b) key |= static_cast<uint64_t>((c >> b) & 1u) << (3 * b + a);
    }
    keys.push_back(key);
  }
  std::sort(keys.begin(), keys.end());
  size_t cells_all_levels = 0;
  for (int shift = 0; shift < 3 * depth; shift += 3) {
    size_t level = 1;
    for (size_t i = 1; i < keys.size(); ++i) level += (keys[i] >> shift) != (keys[i - 1] >> shift);
    if (shift == 0) e.occupied_cells = level;
    cells_all_levels += level;
  }
  e.bytes = static_cast<size_t>(kBytesPerPoint * static_cast<double>(n) +
                                kBytesPerCell * static_cast<double>(cells_all_levels));
  return e;
}

namespace {

Status check_options(const MeshOptions& options) {
  if (options.depth < kMinDepth || options.depth > kMaxDepth)
    return invalid_argument("mesh depth must be " + std::to_string(kMinDepth) + " to " +
                            std::to_string(kMaxDepth) + ", got " + std::to_string(options.depth));
  if (!(options.trim_factor > 0.0) || !std::isfinite(options.trim_factor))
    return invalid_argument("the mesh trim factor must be a positive number");
  return Status::ok();
}

// The usable points as Poisson's input: positions with unit normals, and where each came from.
struct OrientedCloud {
  std::shared_ptr<Cloud> cloud = std::make_shared<Cloud>();
  std::vector<uint32_t> source;  // cloud index -> index in points (colour lookup)
  bool any_color = false;
};

OrientedCloud oriented_cloud(const PointArrays& points) {
  OrientedCloud in;
  in.cloud->reserve(points.size());
  in.source.reserve(points.size());
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3f p = points.position(i), n = points.normal(i);
    if (!usable(p, n)) continue;
    const Eigen::Vector3f u = n.normalized();
    pcl::PointNormal q;
    q.x = p.x(), q.y = p.y(), q.z = p.z();
    q.normal_x = u.x(), q.normal_y = u.y(), q.normal_z = u.z();
    in.cloud->push_back(q);
    in.source.push_back(static_cast<uint32_t>(i));
    const PointState& s = points.state[i];
    in.any_color = in.any_color || s.r || s.g || s.b;
  }
  return in;
}

// Refuses a mesh whose estimated peak memory is over the budget, naming a depth that fits.
Status check_memory_budget(const PointArrays& points, const MeshOptions& options,
                           const MeshReport& r) {
  const size_t budget = options.memory_budget_bytes ? *options.memory_budget_bytes : available_memory_bytes();
  if (!budget || r.estimate.bytes <= budget) return Status::ok();
  std::string hint;
  for (int d = options.depth - 1; d >= kMinDepth && hint.empty(); --d) {
    const MemoryEstimate lower = estimate_memory(points, d);
    if (lower.bytes <= budget)
      hint = "depth " + std::to_string(d) + " (" + millimetres(lower.cell_m) + " cells) needs about " +
             gigabytes(static_cast<double>(lower.bytes));
  }
  if (hint.empty())
    hint = "no depth fits (the points alone need about " +
           gigabytes(kBytesPerPoint * static_cast<double>(r.input_points)) + "): mesh a part of them";
  return invalid_argument("meshing " + std::to_string(r.input_points) + " points at depth " +
                          std::to_string(options.depth) + " (" + millimetres(r.estimate.cell_m) +
                          " cells, " + std::to_string(r.estimate.occupied_cells) +
                          " occupied) needs about " + gigabytes(static_cast<double>(r.estimate.bytes)) +
                          ", more than the " + gigabytes(static_cast<double>(budget)) +
                          (options.memory_budget_bytes ? " allowed" : " available") + "; " + hint);
}

using Tree = pcl::search::KdTree<pcl::PointNormal>;

// Poisson's surface of the cloud at `depth`, searching it with `tree`.
void poisson_surface(const std::shared_ptr<Cloud>& cloud, const std::shared_ptr<Tree>& tree,
                     int depth, Cloud* surface, std::vector<pcl::Vertices>* polygons) {
  pcl::Poisson<pcl::PointNormal> poisson;
  poisson.setDepth(depth);
  poisson.setInputCloud(cloud);
  poisson.setSearchMethod(tree);
  // One thread: PCL's OpenMP loops cover part of Poisson only and spin at their barriers; on the
  // 2-core development machine two threads took twice the CPU time and the wall time of one.
  poisson.setThreads(1);
  poisson.reconstruct(*surface, *polygons);
}

// Trimming: a vertex is supported when its nearest input point is within trim_factor x the
// larger of that point's spacing and the cell (a point's spacing is measured once, when first
// needed). Per surface vertex, its supporting cloud point, or -1.
std::vector<int32_t> supporting_points(const Cloud& surface, const Cloud& cloud, Tree& tree,
                                       double trim_factor, double cell_m) {
  std::vector<float> spacing(cloud.size(), -1.0f);
  std::vector<int32_t> nearest(surface.size(), -1);
  pcl::Indices idx;
  std::vector<float> sq;
  for (size_t v = 0; v < surface.size(); ++v) {
    if (tree.nearestKSearch(surface[v], 1, idx, sq) < 1) continue;
    const int p = idx[0];
    if (spacing[p] < 0.0f) {
      const int found = tree.nearestKSearch(cloud[p], kSpacingNeighbours + 1, idx, sq);
      double sum = 0.0;
      for (int k = 1; k < found; ++k) sum += std::sqrt(static_cast<double>(sq[k]));
      spacing[p] = found > 1 ? static_cast<float>(sum / (found - 1)) : 0.0f;
    }
    const double limit = trim_factor * std::max<double>(spacing[p], cell_m);
    nearest[v] = (surface[v].getVector3fMap() - cloud[p].getVector3fMap()).norm() <= limit ? p : -1;
  }
  return nearest;
}

// The triangles whose three vertices are supported (and distinct), their vertices renumbered in
// order of first use, coloured by their supporting point when `color`.
TriangleMesh supported_triangles(const Cloud& surface, const std::vector<pcl::Vertices>& polygons,
                                 const std::vector<int32_t>& nearest, const OrientedCloud& in,
                                 const PointArrays& points, bool color, MeshReport* r) {
  TriangleMesh mesh;
  std::vector<int64_t> remap(surface.size(), -1);
  for (const pcl::Vertices& poly : polygons) {
    const auto& t = poly.vertices;
    if (t.size() != 3 || nearest[t[0]] < 0 || nearest[t[1]] < 0 || nearest[t[2]] < 0 ||
        t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) {
      ++r->trimmed_triangles;
      continue;
    }
    std::array<uint32_t, 3> tri;
    for (int k = 0; k < 3; ++k) {
      const auto v = static_cast<size_t>(t[k]);
      if (remap[v] < 0) {
        remap[v] = static_cast<int64_t>(mesh.vertex_m.size());
        mesh.vertex_m.push_back(surface[v].getVector3fMap());
        if (color) {
          const PointState& s = points.state[in.source[static_cast<size_t>(nearest[v])]];
          mesh.vertex_rgb.push_back({s.r, s.g, s.b});
        }
      }
      tri[k] = static_cast<uint32_t>(remap[v]);
    }
    mesh.triangles.push_back(tri);
  }
  return mesh;
}

}  // namespace

Result<TriangleMesh> mesh_points(const PointArrays& points, const MeshOptions& options,
                                 MeshReport* report) {
  MeshReport local;
  MeshReport& r = report ? *report : local;
  r = MeshReport{};
  if (Status s = check_options(options); !s) return s;

  const OrientedCloud in = oriented_cloud(points);
  r.input_points = in.cloud->size();
  if (in.cloud->size() < 100)
    return invalid_argument("too few points to mesh: " + std::to_string(in.cloud->size()) +
                            " with a position and a normal (at least 100)");
  r.estimate = estimate_memory(points, options.depth);
  if (Status s = check_memory_budget(points, options, r); !s) return s;

  // One k-d tree serves Poisson (which wants a search method) and the trimming.
  auto tree = std::make_shared<Tree>(false);
  Cloud surface;
  std::vector<pcl::Vertices> polygons;
  poisson_surface(in.cloud, tree, options.depth, &surface, &polygons);
  r.poisson_vertices = surface.size();
  r.poisson_triangles = polygons.size();
  if (surface.empty() || polygons.empty())
    return internal_error("Poisson reconstruction of " + std::to_string(r.input_points) +
                          " points gave no surface");

  const std::vector<int32_t> nearest =
      supporting_points(surface, *in.cloud, *tree, options.trim_factor, r.estimate.cell_m);
  return supported_triangles(surface, polygons, nearest, in, points,
                             options.with_color && in.any_color, &r);
}

}  // namespace depthfuse::mesh
