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

}  // namespace

Result<PointArrays> read_ply(const std::string& path) {
  DF_RETURN_IF_ERROR(check_input_file(path, "cloud"));
  std::ifstream in(path, std::ios::binary);
  if (!in) return not_found("cannot open " + path);
  std::string line;
  if (!std::getline(in, line) || line.rfind("ply", 0) != 0) return corrupt(path + ": not a PLY file");
  std::string format;
  size_t count = 0;
  bool in_vertex = false, seen_vertex = false;
  std::vector<PlyProperty> props;
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream ls(line);
    std::string word;
    ls >> word;
    if (word == "format") ls >> format;
    else if (word == "element") {
      std::string name;
      ls >> name;
      in_vertex = name == "vertex";
      if (in_vertex) {
        // Digits only: an istream reads "-1" into a size_t as 2^64 - 1.
        std::string digits;
        ls >> digits;
        char* end = nullptr;
        errno = 0;
        const unsigned long long n = std::strtoull(digits.c_str(), &end, 10);
        if (digits.empty() || digits[0] < '0' || digits[0] > '9' || *end || errno == ERANGE)
          return corrupt(path + ": bad vertex count '" + digits + "'");
        count = static_cast<size_t>(n);
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
      props.push_back(p);
    } else if (word == "end_header") {
      break;
    }
  }
  if (!seen_vertex) return corrupt(path + ": no vertex element");
  if (format != "binary_little_endian" && format != "ascii")
    return unsupported(path + ": PLY format '" + format + "' (binary_little_endian or ascii only)");
  auto find = [&](const char* n) -> int {
    for (size_t i = 0; i < props.size(); ++i)
      if (props[i].name == n) return static_cast<int>(i);
    return -1;
  };
  const int ix = find("x"), iy = find("y"), iz = find("z");
  if (ix < 0 || iy < 0 || iz < 0) return corrupt(path + ": vertices have no x, y, z");
  const int inx = find("nx"), iny = find("ny"), inz = find("nz");
  const int ir = find("red"), ig = find("green"), ib = find("blue");
  const int im = find("merges"), iv = find("violations");

  size_t stride = 0;
  for (const auto& p : props) stride += p.size;
  // The declared count against what the file holds, before anything is allocated for it: a binary
  // vertex takes `stride` bytes, an ASCII one at least a digit and a separator per property.
  const std::streamoff header_end = in.tellg();
  in.seekg(0, std::ios::end);
  const auto body = static_cast<size_t>(std::max<std::streamoff>(0, in.tellg() - header_end));
  in.seekg(header_end);
  const size_t min_vertex_bytes = format == "ascii" ? 2 * props.size() : stride;
  if (count > body / min_vertex_bytes)
    return corrupt(path + ": truncated: the header declares " + std::to_string(count) +
                   " vertices, the file holds " +
                   std::to_string(body) + " bytes after it (room for at most " +
                   std::to_string(body / min_vertex_bytes) + ")");

  PointArrays a;
  a.reserve(count);
  std::vector<double> vals(props.size());
  std::vector<char> row(stride);
  for (size_t n = 0; n < count; ++n) {
    if (format == "ascii") {
      for (size_t k = 0; k < props.size(); ++k)
        if (!(in >> vals[k])) return corrupt(path + ": truncated at vertex " + std::to_string(n));
    } else {
      if (!in.read(row.data(), static_cast<std::streamsize>(stride)))
        return corrupt(path + ": truncated at vertex " + std::to_string(n) + " of " +
                       std::to_string(count));
      size_t off = 0;
      for (size_t k = 0; k < props.size(); ++k) {
        vals[k] = read_scalar(row.data() + off, props[k].type);
        off += props[k].size;
      }
    }
    PointRecord r;
    r.position_m = {static_cast<float>(vals[ix]), static_cast<float>(vals[iy]), static_cast<float>(vals[iz])};
    if (inx >= 0 && iny >= 0 && inz >= 0)
      r.normal = {static_cast<float>(vals[inx]), static_cast<float>(vals[iny]), static_cast<float>(vals[inz])};
    if (ir >= 0 && ig >= 0 && ib >= 0) {
      r.rgb[0] = static_cast<uint8_t>(vals[ir]);
      r.rgb[1] = static_cast<uint8_t>(vals[ig]);
      r.rgb[2] = static_cast<uint8_t>(vals[ib]);
    }
    if (im >= 0) r.merges = static_cast<uint16_t>(vals[im]);
    if (iv >= 0) r.violations = static_cast<uint16_t>(vals[iv]);
    a.push_back(r);
  }
  return a;
}

}  // namespace depthfuse
