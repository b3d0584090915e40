// The mesh options export and reconstruct share (--mesh-depth, --mesh-trim, --mesh-memory-mb), and
// the lines they print about a mesh.
#pragma once

#include <string>

#include "cli_util.hpp"
#include "depthfuse/mesh/surface_mesh.hpp"

namespace depthfuse::cli {

// The option names, for Args::unknown().
inline const std::vector<std::string>& mesh_option_names() {
  static const std::vector<std::string> names = {"mesh-depth", "mesh-trim", "mesh-memory-mb"};
  return names;
}

// The first mesh option given (its name without "--"), for a command line without --mesh; "" if none.
std::string mesh_option_without_mesh(const Args& args);

// False with the reason in *error for a value out of range.
bool parse_mesh_options(const Args& args, mesh::MeshOptions* options, std::string* error);

// A mesh is written as PLY: the path must end in .ply.
Status check_mesh_path(const std::string& path);

// Writes the mesh and returns the report's lines: "mesh: V vertices, T triangles (... trimmed) ...".
Result<std::string> write_mesh(const std::string& path, const mesh::TriangleMesh& mesh,
                               const mesh::MeshReport& report, double seconds);

}  // namespace depthfuse::cli
