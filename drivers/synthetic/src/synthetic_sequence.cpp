#include "depthfuse/synthetic/synthetic_sequence.hpp"

#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>

#include "random.hpp"
#include "toml_util.hpp"

namespace depthfuse::synthetic {

namespace tu = toml_util;

namespace {
constexpr double kPi = 3.14159265358979323846;
constexpr int kMaxFrames = 100000000;  // ~39 days at 30 Hz; beyond is a typo
}  // namespace

Status SyntheticConfig::validate() const {
  if (frames < 1 || frames > kMaxFrames)
    return invalid_argument("frames must be in [1, " + std::to_string(kMaxFrames) + "], got " +
                            std::to_string(frames));
  if (!(pose_noise_m >= 0.0) || !std::isfinite(pose_noise_m))
    return invalid_argument("pose_noise_m must be finite and >= 0, got " +
                            std::to_string(pose_noise_m));
  if (!(pose_noise_deg >= 0.0) || !std::isfinite(pose_noise_deg))
    return invalid_argument("pose_noise_deg must be finite and >= 0, got " +
                            std::to_string(pose_noise_deg));
  if (!(rate_hz > 0.0) || !std::isfinite(rate_hz))
    return invalid_argument("rate_hz must be finite and > 0, got " + std::to_string(rate_hz));
  RendererConfig rc{intrinsics, noise, min_depth_m, max_depth_m};
  return rc.validate();
}

int default_frames(SceneKind kind) {
  switch (kind) {
    case SceneKind::kFurnished:
    case SceneKind::kPlain:
      return 1200;
    case SceneKind::kCorner:
    case SceneKind::kRoom:
    case SceneKind::kRooms:
      break;
  }
  return SyntheticConfig().frames;
}

Pose perturb_pose(const Pose& T_world_cam, double noise_m, double noise_deg, uint64_t key) {
  if (noise_m <= 0.0 && noise_deg <= 0.0) return T_world_cam;
  double g[8];
  for (int k = 0; k < 4; ++k)
    detail::gaussian_pair(detail::mix64(key + 4 * k), detail::mix64(key + 4 * k + 1), &g[2 * k],
                          &g[2 * k + 1]);
  Pose T = T_world_cam;
  T.translation() += noise_m * Eigen::Vector3d(g[0], g[1], g[2]);
  Eigen::Vector3d axis(g[3], g[4], g[5]);
  const double n = axis.norm();
  axis = n > 1e-12 ? Eigen::Vector3d(axis / n) : Eigen::Vector3d::UnitZ();
  const double angle_rad = noise_deg * kPi / 180.0 * g[6];
  T.linear() = T_world_cam.linear() * Eigen::AngleAxisd(angle_rad, axis).toRotationMatrix();
  return T;
}

Result<SyntheticSequence> SyntheticSequence::create(const SyntheticConfig& config) {
  DF_RETURN_IF_ERROR(config.validate());
  SyntheticSequence s;
  s.config_ = config;
  s.scene_ = std::make_shared<const Scene>(Scene::make(config.scene, config.seed));
  if (s.scene_->primitives().empty())
    return internal_error(std::string("the built-in scene '") + to_string(config.scene) +
                          "' failed to build");
  s.trajectory_ = Trajectory(config.scene, static_cast<size_t>(config.frames), config.rate_hz);
  s.renderer_ = DepthRenderer(s.scene_, RendererConfig{config.intrinsics, config.noise,
                                                       config.min_depth_m, config.max_depth_m});
  return s;
}

Pose SyntheticSequence::T_world_cam_perturbed(size_t i) const {
  return perturb_pose(T_world_cam_true(i), config_.pose_noise_m, config_.pose_noise_deg,
                      detail::stream_key(config_.seed, detail::kStreamPosePerturbation, i));
}

int64_t SyntheticSequence::utime(size_t i) const {
  return static_cast<int64_t>(std::llround(static_cast<double>(i) * 1e6 / config_.rate_hz));
}

void SyntheticSequence::render_into(size_t i, bool with_noise, Frame* frame,
                                    bool with_color) const {
  frame->utime = utime(i);
  frame->sequence = static_cast<uint32_t>(i);
  frame->sensor_serial = "synthetic";
  frame->intrinsics = config_.intrinsics;
  renderer_.render(T_world_cam_true(i),
                   detail::stream_key(config_.seed, detail::kStreamPixelNoise, i), with_noise,
                   &frame->depth, with_color ? &frame->color : nullptr);
  if (!with_color) frame->color = ColorImage();
  if (config_.pose_hints)
    frame->T_world_cam_hint = T_world_cam_perturbed(i);
  else
    frame->T_world_cam_hint.reset();
}

Frame SyntheticSequence::render(size_t i, bool with_noise) const {
  Frame frame;
  render_into(i, with_noise, &frame, true);
  return frame;
}

// ---- [generator] TOML

std::string synthetic_config_to_toml(const SyntheticConfig& c) {
  std::ostringstream o;
  const NoiseConfig& n = c.noise;
  o << "# The settings that generated this data (depthfuse synthetic source).\n"
    << "[generator]\n"
    << "scene = " << tu::quote(to_string(c.scene)) << "\n"
    << "frames = " << c.frames << "\n";
  // TOML integers are signed 64-bit: larger seeds are written as decimal strings.
  if (c.seed <= static_cast<uint64_t>(std::numeric_limits<int64_t>::max()))
    o << "seed = " << c.seed << "\n";
  else
    o << "seed = \"" << c.seed << "\"\n";
  o << "pose_noise_m = " << tu::format_double(c.pose_noise_m) << "\n"
    << "pose_noise_deg = " << tu::format_double(c.pose_noise_deg) << "\n"
    << "rate_hz = " << tu::format_double(c.rate_hz) << "\n"
    << "min_depth_m = " << tu::format_double(c.min_depth_m) << "\n"
    << "max_depth_m = " << tu::format_double(c.max_depth_m) << "\n"
    << "\n[generator.intrinsics]\n"
    << "width = " << c.intrinsics.width << "\n"
    << "height = " << c.intrinsics.height << "\n"
    << "fx = " << tu::format_double(c.intrinsics.fx) << "\n"
    << "fy = " << tu::format_double(c.intrinsics.fy) << "\n"
    << "cx = " << tu::format_double(c.intrinsics.cx) << "\n"
    << "cy = " << tu::format_double(c.intrinsics.cy) << "\n"
    << "\n[generator.noise]\n"
    << "enabled = " << (n.enabled ? "true" : "false") << "\n"
    << "axial_enabled = " << (n.axial_enabled ? "true" : "false") << "\n"
    << "axial_scale = " << tu::format_double(n.axial_scale) << "\n"
    << "axial_max_incidence_deg = " << tu::format_double(n.axial_max_incidence_deg) << "\n"
    << "flying_enabled = " << (n.flying_enabled ? "true" : "false") << "\n"
    << "flying_probability = " << tu::format_double(n.flying_probability) << "\n"
    << "flying_min_jump_m = " << tu::format_double(n.flying_min_jump_m) << "\n"
    << "flying_min_jump_fraction = " << tu::format_double(n.flying_min_jump_fraction) << "\n"
    << "mpi_enabled = " << (n.mpi_enabled ? "true" : "false") << "\n"
    << "mpi_max_bias_m = " << tu::format_double(n.mpi_max_bias_m) << "\n"
    << "mpi_range_m = " << tu::format_double(n.mpi_range_m) << "\n"
    << "dropout_enabled = " << (n.dropout_enabled ? "true" : "false") << "\n"
    << "dropout_probability = " << tu::format_double(n.dropout_probability) << "\n"
    << "dropout_grazing_start_deg = " << tu::format_double(n.dropout_grazing_start_deg) << "\n"
    << "dropout_far_start_m = " << tu::format_double(n.dropout_far_start_m) << "\n"
    << "dropout_far_probability = " << tu::format_double(n.dropout_far_probability) << "\n"
    << "outlier_enabled = " << (n.outlier_enabled ? "true" : "false") << "\n"
    << "outlier_probability = " << tu::format_double(n.outlier_probability) << "\n";
  return o.str();
}

Result<SyntheticConfig> parse_synthetic_config_toml(const std::string& text,
                                                    const std::string& origin) {
  Result<toml::table> parsed = tu::parse(text, origin);
  if (!parsed.is_ok()) return parsed.status();
  const toml::table* g = parsed.value()["generator"].as_table();
  if (!g) return invalid_argument(origin + ": no [generator] table");
  DF_RETURN_IF_ERROR(
      tu::check_keys(*g,
                     {"scene", "frames", "seed", "pose_noise_m", "pose_noise_deg", "rate_hz",
                      "min_depth_m", "max_depth_m", "intrinsics", "noise"},
                     origin, "[generator]"));
  SyntheticConfig c;
  std::string scene = to_string(c.scene);
  DF_RETURN_IF_ERROR(tu::read_string(*g, "scene", origin, &scene));
  Result<SceneKind> kind = parse_scene_kind(scene);
  if (!kind.is_ok())
    return kind.status().with_context(tu::where(origin, *g->get("scene")) + "[generator] scene");
  c.scene = kind.value();
  int64_t frames = c.frames;
  DF_RETURN_IF_ERROR(tu::read_int(*g, "frames", origin, &frames));
  if (frames < 1 || frames > std::numeric_limits<int>::max())
    return invalid_argument(tu::where(origin, *g->get("frames")) + "'frames' must be >= 1");
  c.frames = static_cast<int>(frames);
  if (const toml::node* s = g->get("seed")) {
    if (auto v = s->value_exact<int64_t>(); v && *v >= 0) {
      c.seed = static_cast<uint64_t>(*v);
    } else if (auto str = s->value_exact<std::string>()) {
      try {
        size_t used = 0;
        c.seed = std::stoull(*str, &used, 10);
        if (used != str->size()) throw std::invalid_argument("trailing characters");
      } catch (const std::exception&) {
        return invalid_argument(tu::where(origin, *s) + "'seed' must be a non-negative integer");
      }
    } else {
      return invalid_argument(tu::where(origin, *s) + "'seed' must be a non-negative integer");
    }
  }
  DF_RETURN_IF_ERROR(tu::read_double(*g, "pose_noise_m", origin, &c.pose_noise_m));
  DF_RETURN_IF_ERROR(tu::read_double(*g, "pose_noise_deg", origin, &c.pose_noise_deg));
  DF_RETURN_IF_ERROR(tu::read_double(*g, "rate_hz", origin, &c.rate_hz));
  DF_RETURN_IF_ERROR(tu::read_double(*g, "min_depth_m", origin, &c.min_depth_m));
  DF_RETURN_IF_ERROR(tu::read_double(*g, "max_depth_m", origin, &c.max_depth_m));
  if (const toml::node* node = g->get("intrinsics")) {
    const toml::table* t = node->as_table();
    if (!t) return invalid_argument(tu::where(origin, *node) + "'intrinsics' must be a table");
    DF_RETURN_IF_ERROR(tu::check_keys(*t, {"width", "height", "fx", "fy", "cx", "cy"}, origin,
                                      "[generator.intrinsics]"));
    int64_t w = c.intrinsics.width, h = c.intrinsics.height;
    DF_RETURN_IF_ERROR(tu::read_int(*t, "width", origin, &w));
    DF_RETURN_IF_ERROR(tu::read_int(*t, "height", origin, &h));
    if (w < 1 || h < 1 || w > 65536 || h > 65536)
      return invalid_argument(tu::where(origin, *t) + "image size out of range");
    c.intrinsics.width = static_cast<int>(w);
    c.intrinsics.height = static_cast<int>(h);
    DF_RETURN_IF_ERROR(tu::read_double(*t, "fx", origin, &c.intrinsics.fx));
    DF_RETURN_IF_ERROR(tu::read_double(*t, "fy", origin, &c.intrinsics.fy));
    DF_RETURN_IF_ERROR(tu::read_double(*t, "cx", origin, &c.intrinsics.cx));
    DF_RETURN_IF_ERROR(tu::read_double(*t, "cy", origin, &c.intrinsics.cy));
  }
  if (const toml::node* node = g->get("noise")) {
    const toml::table* t = node->as_table();
    if (!t) return invalid_argument(tu::where(origin, *node) + "'noise' must be a table");
    NoiseConfig& n = c.noise;
    DF_RETURN_IF_ERROR(tu::check_keys(
        *t,
        {"enabled", "axial_enabled", "axial_scale", "axial_max_incidence_deg", "flying_enabled",
         "flying_probability", "flying_min_jump_m", "flying_min_jump_fraction", "mpi_enabled",
         "mpi_max_bias_m", "mpi_range_m", "dropout_enabled", "dropout_probability",
         "dropout_grazing_start_deg", "dropout_far_start_m", "dropout_far_probability",
         "outlier_enabled", "outlier_probability"},
        origin, "[generator.noise]"));
    DF_RETURN_IF_ERROR(tu::read_bool(*t, "enabled", origin, &n.enabled));
    DF_RETURN_IF_ERROR(tu::read_bool(*t, "axial_enabled", origin, &n.axial_enabled));
    DF_RETURN_IF_ERROR(tu::read_double(*t, "axial_scale", origin, &n.axial_scale));
    DF_RETURN_IF_ERROR(
        tu::read_double(*t, "axial_max_incidence_deg", origin, &n.axial_max_incidence_deg));
    DF_RETURN_IF_ERROR(tu::read_bool(*t, "flying_enabled", origin, &n.flying_enabled));
    DF_RETURN_IF_ERROR(tu::read_double(*t, "flying_probability", origin, &n.flying_probability));
    DF_RETURN_IF_ERROR(tu::read_double(*t, "flying_min_jump_m", origin, &n.flying_min_jump_m));
    DF_RETURN_IF_ERROR(
        tu::read_double(*t, "flying_min_jump_fraction", origin, &n.flying_min_jump_fraction));
    DF_RETURN_IF_ERROR(tu::read_bool(*t, "mpi_enabled", origin, &n.mpi_enabled));
    DF_RETURN_IF_ERROR(tu::read_double(*t, "mpi_max_bias_m", origin, &n.mpi_max_bias_m));
    DF_RETURN_IF_ERROR(tu::read_double(*t, "mpi_range_m", origin, &n.mpi_range_m));
    DF_RETURN_IF_ERROR(tu::read_bool(*t, "dropout_enabled", origin, &n.dropout_enabled));
    DF_RETURN_IF_ERROR(tu::read_double(*t, "dropout_probability", origin, &n.dropout_probability));
    DF_RETURN_IF_ERROR(
        tu::read_double(*t, "dropout_grazing_start_deg", origin, &n.dropout_grazing_start_deg));
    DF_RETURN_IF_ERROR(tu::read_double(*t, "dropout_far_start_m", origin, &n.dropout_far_start_m));
    DF_RETURN_IF_ERROR(
        tu::read_double(*t, "dropout_far_probability", origin, &n.dropout_far_probability));
    DF_RETURN_IF_ERROR(tu::read_bool(*t, "outlier_enabled", origin, &n.outlier_enabled));
    DF_RETURN_IF_ERROR(tu::read_double(*t, "outlier_probability", origin, &n.outlier_probability));
  }
  Status st = c.validate();
  if (!st.is_ok()) return st.with_context(origin + ": [generator]");
  return c;
}

}  // namespace depthfuse::synthetic
