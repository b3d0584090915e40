// The mesh's PLY file: header, vertices, faces, written through one buffer per block.
#include <unistd.h>

#include <cstdio>
#include <cstring>
#include <string>

#include "depthfuse/base/errno_text.hpp"
#include "depthfuse/mesh/triangle_mesh.hpp"

namespace depthfuse::mesh {

namespace {

static_assert(sizeof(float) == 4 && sizeof(int32_t) == 4, "PLY float and int are 4 bytes");

// Appends the bytes of v (x86-64 is little-endian, as the header says).
template <typename T>
void put(std::vector<char>* out, const T& v) {
  const size_t at = out->size();
  out->resize(at + sizeof(T));
  std::memcpy(out->data() + at, &v, sizeof(T));
}

Status write_all(std::FILE* f, const std::string& path, const char* data, size_t n) {
  if (n && std::fwrite(data, 1, n, f) != n) return io_error("writing " + path + ": " + errno_text());
  return Status::ok();
}

Status write_body(std::FILE* f, const std::string& path, const TriangleMesh& mesh) {
  std::string header = "ply\nformat binary_little_endian 1.0\ncomment depthfuse mesh\n";
  header += "element vertex " + std::to_string(mesh.vertex_m.size()) + "\n";
  header += "property float x\nproperty float y\nproperty float z\n";
  if (mesh.has_color()) header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  header += "element face " + std::to_string(mesh.triangles.size()) + "\n";
  header += "property list uchar int vertex_indices\nend_header\n";
  DF_RETURN_IF_ERROR(write_all(f, path, header.data(), header.size()));

  constexpr size_t kBlock = 1 << 14;
  std::vector<char> buf;
  buf.reserve(kBlock * 15);
  for (size_t i = 0; i < mesh.vertex_m.size(); ++i) {
    for (int k = 0; k < 3; ++k) put(&buf, mesh.vertex_m[i][k]);
    if (mesh.has_color()) buf.insert(buf.end(), mesh.vertex_rgb[i].begin(), mesh.vertex_rgb[i].end());
    if ((i + 1) % kBlock == 0) {
      DF_RETURN_IF_ERROR(write_all(f, path, buf.data(), buf.size()));
      buf.clear();
    }
  }
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    put(&buf, uint8_t{3});
    for (uint32_t v : mesh.triangles[t]) put(&buf, static_cast<int32_t>(v));
    if ((t + 1) % kBlock == 0) {
      DF_RETURN_IF_ERROR(write_all(f, path, buf.data(), buf.size()));
      buf.clear();
    }
  }
  return write_all(f, path, buf.data(), buf.size());
}

}  // namespace

Status write_mesh_ply(const std::string& path, const TriangleMesh& mesh) {
  if (mesh.has_color() && mesh.vertex_rgb.size() != mesh.vertex_m.size())
    return invalid_argument("mesh for " + path + ": " + std::to_string(mesh.vertex_rgb.size()) +
                            " colours for " + std::to_string(mesh.vertex_m.size()) + " vertices");
  // The PLY's int indices are signed.
  if (mesh.vertex_m.size() > static_cast<size_t>(INT32_MAX))
    return invalid_argument("mesh for " + path + ": more vertices than a PLY int can index");
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) return io_error("cannot create " + path + ": " + errno_text());
  Status st = write_body(f, path, mesh);
  if (std::fclose(f) != 0 && st) st = io_error("closing " + path + ": " + errno_text());
  if (!st) ::unlink(path.c_str());
  return st;
}

}  // namespace depthfuse::mesh
