// Scene <-> TOML: the analytic ground truth travels with the data it describes.
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "depthfuse/synthetic/scene.hpp"
#include "toml_util.hpp"

namespace depthfuse::synthetic {

namespace tu = toml_util;

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
      << tu::quote(name_) << "\n";
  for (const Primitive& p : primitives_) {
    out << "\n[[primitive]]\n"
        << "kind = " << tu::quote(to_string(p.kind)) << "\n";
    if (!p.name.empty()) out << "name = " << tu::quote(p.name) << "\n";
    out << "color_rgb = [" << int{p.color_rgb[0]} << ", " << int{p.color_rgb[1]} << ", "
        << int{p.color_rgb[2]} << "]\n";
    // Written only when it differs from the default, so older scene files read back the same.
    if (p.checker_m != Primitive().checker_m)
      out << "checker_m = " << tu::format_double(p.checker_m) << "\n";
    if (p.kind == PrimitiveKind::kPlane) {
      out << "origin_m = " << tu::format_vec(p.origin_m) << "\n"
          << "normal = " << tu::format_vec(p.normal) << "\n"
          << "u_axis = " << tu::format_vec(p.u_axis) << "\n"
          << "u_range_m = [" << tu::format_double(p.u_min_m) << ", " << tu::format_double(p.u_max_m)
          << "]\n"
          << "v_range_m = [" << tu::format_double(p.v_min_m) << ", " << tu::format_double(p.v_max_m)
          << "]\n";
    } else {
      out << "min_m = " << tu::format_vec(p.min_m) << "\n"
          << "max_m = " << tu::format_vec(p.max_m) << "\n";
    }
  }
  return out.str();
}

Result<Scene> Scene::parse_toml(const std::string& text, const std::string& origin) {
  Result<toml::table> parsed = tu::parse(text, origin);
  if (!parsed.is_ok()) return parsed.status();
  const toml::table& root = parsed.value();

  std::string name;
  for (auto&& [key, node] : root) {
    const std::string k(key.str());
    if (k == "scene") {
      const toml::table* t = node.as_table();
      if (!t) return invalid_argument(tu::where(origin, node) + "'scene' must be a table");
      DF_RETURN_IF_ERROR(tu::check_keys(*t, {"format_version", "name"}, origin, "[scene]"));
      int64_t version = 1;
      DF_RETURN_IF_ERROR(tu::read_int(*t, "format_version", origin, &version));
      if (version != 1)
        return invalid_argument(tu::where(origin, *t) + "unsupported scene format_version " +
                                std::to_string(version) + " (this build reads version 1)");
      DF_RETURN_IF_ERROR(tu::read_string(*t, "name", origin, &name));
    } else if (k == "primitive") {
      if (!node.is_array_of_tables())
        return invalid_argument(tu::where(origin, node) +
                                "'primitive' must be an array of tables ([[primitive]])");
    } else if (!node.is_table()) {
      // Other tables (e.g. [generator]) belong to other readers; stray keys are mistakes.
      return invalid_argument(tu::where(origin, node) + "unknown key '" + k + "'");
    }
  }

  std::vector<Primitive> primitives;
  if (const toml::array* arr = root["primitive"].as_array()) {
    for (size_t i = 0; i < arr->size(); ++i) {
      const toml::table* t = arr->get(i)->as_table();
      if (!t)
        return invalid_argument(tu::where(origin, *arr->get(i)) + "primitive must be a table");
      std::string kind;
      DF_RETURN_IF_ERROR(tu::read_string(*t, "kind", origin, &kind));
      Primitive p;
      if (kind == "plane") {
        p.kind = PrimitiveKind::kPlane;
        DF_RETURN_IF_ERROR(tu::check_keys(
            *t,
            {"kind", "name", "color_rgb", "checker_m", "origin_m", "normal", "u_axis", "u_range_m",
             "v_range_m"},
            origin, "a plane primitive"));
        DF_RETURN_IF_ERROR(tu::read_vec3(*t, "origin_m", origin, &p.origin_m, true));
        DF_RETURN_IF_ERROR(tu::read_vec3(*t, "normal", origin, &p.normal, true));
        DF_RETURN_IF_ERROR(tu::read_vec3(*t, "u_axis", origin, &p.u_axis, true));
        double u[2], v[2];
        DF_RETURN_IF_ERROR(tu::read_numbers(*t, "u_range_m", origin, 2, u, true));
        DF_RETURN_IF_ERROR(tu::read_numbers(*t, "v_range_m", origin, 2, v, true));
        p.u_min_m = u[0];
        p.u_max_m = u[1];
        p.v_min_m = v[0];
        p.v_max_m = v[1];
      } else if (kind == "box" || kind == "room") {
        p.kind = kind == "box" ? PrimitiveKind::kBox : PrimitiveKind::kRoom;
        DF_RETURN_IF_ERROR(tu::check_keys(*t, {"kind", "name", "color_rgb", "checker_m", "min_m", "max_m"},
                                          origin, "a " + kind + " primitive"));
        DF_RETURN_IF_ERROR(tu::read_vec3(*t, "min_m", origin, &p.min_m, true));
        DF_RETURN_IF_ERROR(tu::read_vec3(*t, "max_m", origin, &p.max_m, true));
      } else {
        return invalid_argument(tu::where(origin, *t) + "primitive " + std::to_string(i) +
                                ": 'kind' must be \"plane\", \"box\" or \"room\", got '" + kind +
                                "'");
      }
      DF_RETURN_IF_ERROR(tu::read_string(*t, "name", origin, &p.name));
      DF_RETURN_IF_ERROR(tu::read_double(*t, "checker_m", origin, &p.checker_m));
      if (t->contains("color_rgb")) {
        double c[3];
        DF_RETURN_IF_ERROR(tu::read_numbers(*t, "color_rgb", origin, 3, c, true));
        for (int k = 0; k < 3; ++k) {
          if (!(c[k] >= 0.0 && c[k] <= 255.0))
            return invalid_argument(tu::where(origin, *t->get("color_rgb")) +
                                    "'color_rgb' values must be in [0, 255]");
          p.color_rgb[static_cast<size_t>(k)] = static_cast<uint8_t>(c[k] + 0.5);
        }
      }
      primitives.push_back(std::move(p));
    }
  }
  Result<Scene> scene = create(std::move(primitives), name);
  if (!scene.is_ok()) return scene.status().with_context(origin);
  return scene;
}

Result<Scene> Scene::load_toml(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return not_found("cannot open scene file '" + path + "'");
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) return io_error("cannot read scene file '" + path + "'");
  return parse_toml(text.str(), path);
}

}  // namespace depthfuse::synthetic
