#include "mesh_options.hpp"

#include <cstdio>

#include "depthfuse/mesh/triangle_mesh.hpp"
#include "depthfuse/store/export.hpp"

namespace depthfuse::cli {

std::string mesh_option_without_mesh(const Args& args) {
  if (args.has("mesh")) return "";
  for (const std::string& name : mesh_option_names())
    if (args.has(name)) return name;
  return "";
}

bool parse_mesh_options(const Args& args, mesh::MeshOptions* options, std::string* error) {
  long depth = options->depth, memory_mb = 0;
  if (!args.get_int("mesh-depth", &depth, error, daemon::closed(mesh::kMinDepth, mesh::kMaxDepth)) ||
      !args.get_double("mesh-trim", &options->trim_factor, error, daemon::open_closed(0, 100)) ||
      !args.get_int("mesh-memory-mb", &memory_mb, error, daemon::closed(1, 1 << 30)))
    return false;
  options->depth = static_cast<int>(depth);
  if (args.has("mesh-memory-mb")) options->memory_budget_bytes = static_cast<size_t>(memory_mb) << 20;
  return true;
}

Status check_mesh_path(const std::string& path) {
  auto format = store::cloud_format_for(path);
  if (!format || *format != CloudFormat::kPly)
    return invalid_argument("a mesh is written as PLY: '" + path + "' must end in .ply");
  return Status::ok();
}

Result<std::string> write_mesh(const std::string& path, const mesh::TriangleMesh& mesh,
                               const mesh::MeshReport& report, double seconds) {
  DF_RETURN_IF_ERROR(mesh::write_mesh_ply(path, mesh));
  char line[512];
  std::snprintf(line, sizeof line,
                "mesh: %zu vertices, %zu triangles%s from %zu points (Poisson %zu triangles, %zu trimmed; "
                "%.1f mm cells, about %.2f GB estimated), %.1f s: %s\n",
                mesh.vertex_m.size(), mesh.triangles.size(), mesh.has_color() ? " with colour" : "",
                report.input_points, report.poisson_triangles, report.trimmed_triangles,
                report.estimate.cell_m * 1e3, static_cast<double>(report.estimate.bytes) / 1e9, seconds,
                path.c_str());
  return std::string(line);
}

}  // namespace depthfuse::cli
