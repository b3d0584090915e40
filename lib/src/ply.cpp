#include "depthfuse/ply.hpp"

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>

#include "depthfuse/input_file.hpp"

namespace depthfuse {

Status write_ply(const std::string& path, const PointArrays& points, const PlyOptions& options) {
  return write_point_cloud(path, CloudFormat::kPly, points, options);
}

namespace {

struct PlyProperty {
  std::string name, type;
  size_t size = 0;
};

size_t type_size(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" || t == "float32") return 4;
  if (t == "double" || t == "float64") return 8;
  return 0;
}

double read_scalar(const char* p, const std::string& t) {
  auto get = [p](auto v) { std::memcpy(&v, p, sizeof(v)); return static_cast<double>(v); };
  if (t == "char" || t == "int8") return get(int8_t{});
  if (t == "uchar" || t == "uint8") return get(uint8_t{});
  if (t == "short" || t == "int16") return get(int16_t{});
  if (t == "ushort" || t == "uint16") return get(uint16_t{});
  if (t == "int" || t == "int32") return get(int32_t{});
  if (t == "uint" || t == "uint32") return get(uint32_t{});
  if (t == "float" || t == "float32") return get(float{});
  return get(double{});
}

// What the header says of the vertex element: its count, its properties in file order, and the
// file's format.
struct PlyHeader {
  std::string format;
  size_t count = 0;
  std::vector<PlyProperty> props;
  size_t stride() const {
    size_t bytes = 0;
    for (const auto& p : props) bytes += p.size;
    return bytes;
  }
};

// Digits only: an istream reads "-1" into a size_t as 2^64 - 1.
Result<size_t> parse_vertex_count(const std::string& digits, const std::string& path) {
  char* end = nullptr;
  errno = 0;
  const unsigned long long n = std::strtoull(digits.c_str(), &end, 10);
  if (digits.empty() || digits[0] < '0' || digits[0] > '9' || *end || errno == ERANGE)
    return corrupt(path + ": bad vertex count '" + digits + "'");
  return static_cast<size_t>(n);
}

// The header up to end_header, leaving `in` at the first vertex.
Result<PlyHeader> read_header(std::istream& in, const std::string& path) {
  std::string line;
  if (!std::getline(in, line) || line.rfind("ply", 0) != 0) return corrupt(path + ": not a PLY file");
  PlyHeader h;
  bool in_vertex = false, seen_vertex = false;
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream ls(line);
    std::string word;
    ls >> word;
    if (word == "format") ls >> h.format;
    else if (word == "element") {
      std::string name;
      ls >> name;
      in_vertex = name == "vertex";
      if (in_vertex) {
        std::string digits;
        ls >> digits;
        auto count = parse_vertex_count(digits, path);
        if (!count) return count.status();
        h.count = *count;
        seen_vertex = true;
      } else if (!seen_vertex) {
        return unsupported(path + ": elements before 'vertex' are not supported");
      }
    } else if (word == "property" && in_vertex) {
      PlyProperty p;
      ls >> p.type;
      if (p.type == "list") return unsupported(path + ": list properties in vertex element");
      ls >> p.name;
      p.size = type_size(p.type);
      if (!p.size) return corrupt(path + ": unknown property type '" + p.type + "'");
      h.props.push_back(p);
    } else if (word == "end_header") {
      break;
    }
  }
  if (!seen_vertex) return corrupt(path + ": no vertex element");
  if (h.format != "binary_little_endian" && h.format != "ascii")
    return unsupported(path + ": PLY format '" + h.format + "' (binary_little_endian or ascii only)");
  return h;
}

// Where each field of a point is among the properties (-1: absent).
struct PlyColumns {
  int x, y, z;
  int nx, ny, nz;
  int red, green, blue;
  int merges, violations;
};

PlyColumns find_columns(const std::vector<PlyProperty>& props) {
  auto find = [&](const char* n) -> int {
    for (size_t i = 0; i < props.size(); ++i)
      if (props[i].name == n) return static_cast<int>(i);
    return -1;
  };
  return {find("x"),   find("y"),     find("z"),    find("nx"),     find("ny"),        find("nz"),
          find("red"), find("green"), find("blue"), find("merges"), find("violations")};
}

// The declared count against what the file holds, before anything is allocated for it: a binary
// vertex takes `stride` bytes, an ASCII one at least a digit and a separator per property.
Status check_vertex_count(std::istream& in, const PlyHeader& h, const std::string& path) {
  const std::streamoff header_end = in.tellg();
  in.seekg(0, std::ios::end);
  const auto body = static_cast<size_t>(std::max<std::streamoff>(0, in.tellg() - header_end));
  in.seekg(header_end);
  const size_t min_vertex_bytes = h.format == "ascii" ? 2 * h.props.size() : h.stride();
  if (h.count > body / min_vertex_bytes)
    return corrupt(path + ": truncated: the header declares " + std::to_string(h.count) +
                   " vertices, the file holds " +
                   std::to_string(body) + " bytes after it (room for at most " +
                   std::to_string(body / min_vertex_bytes) + ")");
  return Status::ok();
}

// Vertex n's property values, in the header's order, into `vals` (`row`: a stride's buffer).
Status read_vertex(std::istream& in, const PlyHeader& h, size_t n, std::vector<char>* row,
                   std::vector<double>* vals, const std::string& path) {
  if (h.format == "ascii") {
    for (size_t k = 0; k < h.props.size(); ++k)
      if (!(in >> (*vals)[k])) return corrupt(path + ": truncated at vertex " + std::to_string(n));
    return Status::ok();
  }
  if (!in.read(row->data(), static_cast<std::streamsize>(row->size())))
    return corrupt(path + ": truncated at vertex " + std::to_string(n) + " of " +
                   std::to_string(h.count));
  size_t off = 0;
  for (size_t k = 0; k < h.props.size(); ++k) {
    (*vals)[k] = read_scalar(row->data() + off, h.props[k].type);
    off += h.props[k].size;
  }
  return Status::ok();
}

PointRecord point_of(const std::vector<double>& vals, const PlyColumns& c) {
  PointRecord r;
  r.position_m = {static_cast<float>(vals[c.x]), static_cast<float>(vals[c.y]), static_cast<float>(vals[c.z])};
  if (c.nx >= 0 && c.ny >= 0 && c.nz >= 0)
    r.normal = {static_cast<float>(vals[c.nx]), static_cast<float>(vals[c.ny]), static_cast<float>(vals[c.nz])};
  if (c.red >= 0 && c.green >= 0 && c.blue >= 0) {
    r.rgb[0] = static_cast<uint8_t>(vals[c.red]);
    r.rgb[1] = static_cast<uint8_t>(vals[c.green]);
    r.rgb[2] = static_cast<uint8_t>(vals[c.blue]);
  }
  if (c.merges >= 0) r.merges = static_cast<uint16_t>(vals[c.merges]);
  if (c.violations >= 0) r.violations = static_cast<uint16_t>(vals[c.violations]);
  return r;
}

}  // namespace

Result<PointArrays> read_ply(const std::string& path) {
  DF_RETURN_IF_ERROR(check_input_file(path, "cloud"));
  std::ifstream in(path, std::ios::binary);
  if (!in) return not_found("cannot open " + path);
  auto header = read_header(in, path);
  if (!header) return header.status();
  const PlyHeader& h = *header;
  const PlyColumns columns = find_columns(h.props);
  if (columns.x < 0 || columns.y < 0 || columns.z < 0)
    return corrupt(path + ": vertices have no x, y, z");
  DF_RETURN_IF_ERROR(check_vertex_count(in, h, path));

  PointArrays a;
  a.reserve(h.count);
  std::vector<double> vals(h.props.size());
  std::vector<char> row(h.stride());
  for (size_t n = 0; n < h.count; ++n) {
    DF_RETURN_IF_ERROR(read_vertex(in, h, n, &row, &vals, path));
    a.push_back(point_of(vals, columns));
  }
  return a;
}

}  // namespace depthfuse
