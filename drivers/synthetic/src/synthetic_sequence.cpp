#include "depthfuse/synthetic/synthetic_sequence.hpp"

#include <cmath>
#include <limits>
#include <optional>
#include <sstream>
#include <string>
#include <utility>

#include "random.hpp"
#include "depthfuse/toml/strict_reader.hpp"
#include "toml_write.hpp"

namespace depthfuse::synthetic {

namespace tw = toml_write;

namespace {
constexpr double kPi = 3.14159265358979323846;
constexpr int kMaxFrames = 100000000;  // ~39 days at 30 Hz; beyond is a typo
}  // namespace

Status SyntheticConfig::validate() const {
  if (frames < 1 || frames > kMaxFrames)
    return invalid_argument("frames must be in [1, " + std::to_string(kMaxFrames) + "], got " +
                            std::to_string(frames));
  if (first_frame < 0 || first_frame >= frames)
    return invalid_argument("first (the first frame streamed) must be in [0, frames - 1] = [0, " +
                            std::to_string(frames - 1) + "], got " + std::to_string(first_frame));
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
    << "scene = " << tw::quote(to_string(c.scene)) << "\n"
    << "frames = " << c.frames << "\n";
  // TOML integers are signed 64-bit: larger seeds are written as decimal strings.
  if (c.seed <= static_cast<uint64_t>(std::numeric_limits<int64_t>::max()))
    o << "seed = " << c.seed << "\n";
  else
    o << "seed = \"" << c.seed << "\"\n";
  o << "pose_noise_m = " << tw::format_double(c.pose_noise_m) << "\n"
    << "pose_noise_deg = " << tw::format_double(c.pose_noise_deg) << "\n"
    << "rate_hz = " << tw::format_double(c.rate_hz) << "\n"
    << "min_depth_m = " << tw::format_double(c.min_depth_m) << "\n"
    << "max_depth_m = " << tw::format_double(c.max_depth_m) << "\n"
    << "\n[generator.intrinsics]\n"
    << "width = " << c.intrinsics.width << "\n"
    << "height = " << c.intrinsics.height << "\n"
    << "fx = " << tw::format_double(c.intrinsics.fx) << "\n"
    << "fy = " << tw::format_double(c.intrinsics.fy) << "\n"
    << "cx = " << tw::format_double(c.intrinsics.cx) << "\n"
    << "cy = " << tw::format_double(c.intrinsics.cy) << "\n"
    << "\n[generator.noise]\n"
    << "enabled = " << (n.enabled ? "true" : "false") << "\n"
    << "axial_enabled = " << (n.axial_enabled ? "true" : "false") << "\n"
    << "axial_scale = " << tw::format_double(n.axial_scale) << "\n"
    << "axial_max_incidence_deg = " << tw::format_double(n.axial_max_incidence_deg) << "\n"
    << "flying_enabled = " << (n.flying_enabled ? "true" : "false") << "\n"
    << "flying_probability = " << tw::format_double(n.flying_probability) << "\n"
    << "flying_min_jump_m = " << tw::format_double(n.flying_min_jump_m) << "\n"
    << "flying_min_jump_fraction = " << tw::format_double(n.flying_min_jump_fraction) << "\n"
    << "mpi_enabled = " << (n.mpi_enabled ? "true" : "false") << "\n"
    << "mpi_max_bias_m = " << tw::format_double(n.mpi_max_bias_m) << "\n"
    << "mpi_range_m = " << tw::format_double(n.mpi_range_m) << "\n"
    << "dropout_enabled = " << (n.dropout_enabled ? "true" : "false") << "\n"
    << "dropout_probability = " << tw::format_double(n.dropout_probability) << "\n"
    << "dropout_grazing_start_deg = " << tw::format_double(n.dropout_grazing_start_deg) << "\n"
    << "dropout_far_start_m = " << tw::format_double(n.dropout_far_start_m) << "\n"
    << "dropout_far_probability = " << tw::format_double(n.dropout_far_probability) << "\n"
    << "outlier_enabled = " << (n.outlier_enabled ? "true" : "false") << "\n"
    << "outlier_probability = " << tw::format_double(n.outlier_probability) << "\n";
  return o.str();
}

Result<SyntheticConfig> parse_synthetic_config_toml(const std::string& text,
                                                    const std::string& origin) {
  using strict_toml::any_number;
  using strict_toml::TableReader;
  Result<toml::table> parsed = strict_toml::parse_document(text, origin);
  if (!parsed.is_ok()) return parsed.status();
  const toml::table& root = parsed.value();
  strict_toml::Diagnostics diagnostics(origin);
  // The document's other tables ([scene], [[primitive]]) are Scene::parse_toml's.
  TableReader top(&root, "", root.source(), &diagnostics, nullptr);
  const toml::table* g = top.table("generator");
  if (g == nullptr) {
    DF_RETURN_IF_ERROR(diagnostics.status());
    return invalid_argument(origin + ": no [generator] table");
  }
  // Types here; the ranges are SyntheticConfig::validate's (one place for each rule).
  SyntheticConfig c;
  TableReader r(g, "generator", g->source(), &diagnostics, nullptr);
  std::string scene = to_string(c.scene);
  r.read("scene", &scene, [](const std::string& s) -> std::optional<std::string> {
    Result<SceneKind> kind = parse_scene_kind(s);
    if (kind.is_ok()) return std::nullopt;
    return kind.status().message();
  });
  r.read("frames", &c.frames, any_number());
  r.read("seed", &c.seed);
  r.read("pose_noise_m", &c.pose_noise_m, any_number());
  r.read("pose_noise_deg", &c.pose_noise_deg, any_number());
  r.read("rate_hz", &c.rate_hz, any_number());
  r.read("min_depth_m", &c.min_depth_m, any_number());
  r.read("max_depth_m", &c.max_depth_m, any_number());
  if (const toml::table* t = r.table("intrinsics")) {
    TableReader k(t, "generator.intrinsics", t->source(), &diagnostics, nullptr);
    k.read("width", &c.intrinsics.width, strict_toml::closed(1, 65536));
    k.read("height", &c.intrinsics.height, strict_toml::closed(1, 65536));
    k.read("fx", &c.intrinsics.fx, any_number());
    k.read("fy", &c.intrinsics.fy, any_number());
    k.read("cx", &c.intrinsics.cx, any_number());
    k.read("cy", &c.intrinsics.cy, any_number());
    k.reject_unknown();
  }
  if (const toml::table* t = r.table("noise")) {
    TableReader k(t, "generator.noise", t->source(), &diagnostics, nullptr);
    NoiseConfig& n = c.noise;
    k.read("enabled", &n.enabled);
    k.read("axial_enabled", &n.axial_enabled);
    k.read("axial_scale", &n.axial_scale, any_number());
    k.read("axial_max_incidence_deg", &n.axial_max_incidence_deg, any_number());
    k.read("flying_enabled", &n.flying_enabled);
    k.read("flying_probability", &n.flying_probability, any_number());
    k.read("flying_min_jump_m", &n.flying_min_jump_m, any_number());
    k.read("flying_min_jump_fraction", &n.flying_min_jump_fraction, any_number());
    k.read("mpi_enabled", &n.mpi_enabled);
    k.read("mpi_max_bias_m", &n.mpi_max_bias_m, any_number());
    k.read("mpi_range_m", &n.mpi_range_m, any_number());
    k.read("dropout_enabled", &n.dropout_enabled);
    k.read("dropout_probability", &n.dropout_probability, any_number());
    k.read("dropout_grazing_start_deg", &n.dropout_grazing_start_deg, any_number());
    k.read("dropout_far_start_m", &n.dropout_far_start_m, any_number());
    k.read("dropout_far_probability", &n.dropout_far_probability, any_number());
    k.read("outlier_enabled", &n.outlier_enabled);
    k.read("outlier_probability", &n.outlier_probability, any_number());
    k.reject_unknown();
  }
  r.reject_unknown();
  DF_RETURN_IF_ERROR(diagnostics.status());
  c.scene = parse_scene_kind(scene).value();
  Status st = c.validate();
  if (!st.is_ok()) return st.with_context(origin + ": [generator]");
  return c;
}

}  // namespace depthfuse::synthetic
