// Scene <-> TOML: the analytic ground truth travels with the data it describes.
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

#include "depthfuse/input_file.hpp"
#include "depthfuse/synthetic/scene.hpp"
#include "depthfuse/toml/strict_reader.hpp"
#include "toml_write.hpp"

namespace depthfuse::synthetic {

namespace tw = toml_write;

std::string Scene::to_toml() const {
  std::ostringstream out;
  out << "# depthfuse synthetic scene: the analytic ground truth of the data beside it.\n"
         "# Metres, world frame (z up). kind = plane: the points origin_m + a u_axis + b v_axis "
         "with\n"
         "# a in u_range_m, b in v_range_m, v_axis = normal x u_axis, normal towards the free "
         "side;\n"
         "# kind = box: a solid box [min_m, max_m]; kind = room: the inside of the box [min_m, "
         "max_m].\n"
         "[scene]\n"
         "format_version = 1\n"
         "name = "
      << tw::quote(name_) << "\n";
  for (const Primitive& p : primitives_) {
    out << "\n[[primitive]]\n"
        << "kind = " << tw::quote(to_string(p.kind)) << "\n";
    if (!p.name.empty()) out << "name = " << tw::quote(p.name) << "\n";
    out << "color_rgb = [" << int{p.color_rgb[0]} << ", " << int{p.color_rgb[1]} << ", "
        << int{p.color_rgb[2]} << "]\n";
    // Written only when it differs from the default, so older scene files read back the same.
    if (p.checker_m != Primitive().checker_m)
      out << "checker_m = " << tw::format_double(p.checker_m) << "\n";
    if (p.kind == PrimitiveKind::kPlane) {
      out << "origin_m = " << tw::format_vec(p.origin_m) << "\n"
          << "normal = " << tw::format_vec(p.normal) << "\n"
          << "u_axis = " << tw::format_vec(p.u_axis) << "\n"
          << "u_range_m = [" << tw::format_double(p.u_min_m) << ", " << tw::format_double(p.u_max_m)
          << "]\n"
          << "v_range_m = [" << tw::format_double(p.v_min_m) << ", " << tw::format_double(p.v_max_m)
          << "]\n";
    } else {
      out << "min_m = " << tw::format_vec(p.min_m) << "\n"
          << "max_m = " << tw::format_vec(p.max_m) << "\n";
    }
  }
  return out.str();
}

namespace {

using strict_toml::TableReader;

// An array of three numbers into a vector (left as it is when absent or rejected).
void read_vec3(TableReader& r, std::string_view key, Eigen::Vector3d* v) {
  r.require(key);
  double xyz[3] = {v->x(), v->y(), v->z()};
  r.read(key, xyz, 3, strict_toml::any_number());
  *v = Eigen::Vector3d(xyz[0], xyz[1], xyz[2]);
}

// One [[primitive]] table. Its geometry is checked by Scene::create.
Primitive read_primitive(TableReader& r) {
  Primitive p;
  std::string kind;
  r.require("kind");
  r.read("kind", &kind, strict_toml::one_of({"plane", "box", "room"}));
  if (!r.clean()) return p;  // which keys belong depends on the kind
  r.read("name", &p.name, strict_toml::any_string());
  double rgb[3] = {static_cast<double>(p.color_rgb[0]), static_cast<double>(p.color_rgb[1]),
                   static_cast<double>(p.color_rgb[2])};
  r.read("color_rgb", rgb, 3, strict_toml::closed(0.0, 255.0));
  for (size_t k = 0; k < 3; ++k) p.color_rgb[k] = static_cast<uint8_t>(rgb[k] + 0.5);
  r.read("checker_m", &p.checker_m, strict_toml::non_negative());
  if (kind == "plane") {
    p.kind = PrimitiveKind::kPlane;
    read_vec3(r, "origin_m", &p.origin_m);
    read_vec3(r, "normal", &p.normal);
    read_vec3(r, "u_axis", &p.u_axis);
    // Infinite bounds make a half-plane, a strip or a whole plane.
    double u[2] = {p.u_min_m, p.u_max_m}, v[2] = {p.v_min_m, p.v_max_m};
    r.require("u_range_m");
    r.read("u_range_m", u, 2, strict_toml::any_number_or_infinity());
    r.require("v_range_m");
    r.read("v_range_m", v, 2, strict_toml::any_number_or_infinity());
    p.u_min_m = u[0];
    p.u_max_m = u[1];
    p.v_min_m = v[0];
    p.v_max_m = v[1];
  } else {
    p.kind = kind == "box" ? PrimitiveKind::kBox : PrimitiveKind::kRoom;
    read_vec3(r, "min_m", &p.min_m);
    read_vec3(r, "max_m", &p.max_m);
  }
  r.reject_unknown();
  return p;
}

}  // namespace

Result<Scene> Scene::parse_toml(const std::string& text, const std::string& origin) {
  Result<toml::table> parsed = strict_toml::parse_document(text, origin);
  if (!parsed.is_ok()) return parsed.status();
  const toml::table& root = parsed.value();
  strict_toml::Diagnostics diagnostics(origin);
  TableReader top(&root, "", root.source(), &diagnostics, nullptr);

  std::string name;
  if (const toml::table* t = top.table("scene")) {
    TableReader r(t, "scene", t->source(), &diagnostics, nullptr);
    int version = 1;
    r.read("format_version", &version, strict_toml::any_number());
    if (version != 1)
      r.fail("format_version", "unsupported scene format_version " + std::to_string(version) +
                                   " (this build reads version 1)");
    r.read("name", &name, strict_toml::any_string());
    r.reject_unknown();
  }
  std::vector<Primitive> primitives;
  if (const toml::array* arr = top.array_of_tables("primitive")) {
    for (size_t i = 0; i < arr->size(); ++i) {
      const toml::table* t = arr->get(i)->as_table();
      TableReader r(t, "primitive[" + std::to_string(i) + "]", t->source(), &diagnostics, nullptr);
      primitives.push_back(read_primitive(r));
    }
  }
  // Other tables (the [generator] that write_tum_folder adds) belong to other readers; stray keys
  // are mistakes.
  for (auto&& [key, node] : root)
    if (node.is_table()) top.table(key.str());
  top.reject_unknown();
  DF_RETURN_IF_ERROR(diagnostics.status());

  Result<Scene> scene = create(std::move(primitives), name);
  if (!scene.is_ok()) return scene.status().with_context(origin);
  return scene;
}

Result<Scene> Scene::load_toml(const std::string& path) {
  // A scene is a list of primitives: kilobytes.
  auto text = read_input_file(path, "scene file", size_t{16} << 20);
  if (!text) return text.status();
  return parse_toml(*text, path);
}

}  // namespace depthfuse::synthetic
