// Loads config/depthfuse.toml (see the file itself for what every key means and where the default
// comes from). The rules here are the ranges a daemon can run with; anything else is an error with
// its file, line and key, and an unknown key is an error too (a typo must not be silently ignored).
#include "depthfuse/app_config.hpp"

#include <algorithm>
#include <cmath>
#include <exception>

#include "app_config_trace.hpp"
#include "depthfuse/base/errno_text.hpp"
#include "depthfuse/input_file.hpp"
#include "depthfuse/toml/strict_reader.hpp"

namespace depthfuse {
namespace {

using strict_toml::any_number;
using strict_toml::any_string;
using strict_toml::at_least;
using strict_toml::closed;
using strict_toml::Diagnostics;
using strict_toml::format_number;
using strict_toml::KeyTrace;
using strict_toml::non_empty;
using strict_toml::non_negative;
using strict_toml::one_of;
using strict_toml::open_closed;
using strict_toml::positive;
using strict_toml::StringRule;
using strict_toml::TableReader;

// A config file is a few kilobytes; anything this large is not one.
constexpr size_t kMaxConfigBytes = 1 << 20;
// No depth sensor's image has a side this long (Kinect V2: 512 px, TUM's Kinect v1: 640).
constexpr int kMaxFrameSidePx = 4096;

// Reports `hi_key` when it does not exceed `lo_key`.
void require_greater(TableReader& r, const char* hi_key, double hi, const char* lo_key, double lo) {
  if (!(hi > lo)) {
    r.fail(hi_key, std::string("must be > ") + lo_key + " (" + format_number(lo) + "), got " +
                       format_number(hi));
  }
}

void read_sensor(TableReader& r, SensorModelConfig* s) {
  r.read("lambda1", &s->lambda1, positive());
  r.read("lambda2", &s->lambda2, positive());
  r.read("beta_x_rad", &s->beta_x_rad, non_negative());
  r.read("beta_y_rad", &s->beta_y_rad, non_negative());
  r.read("alpha0_m", &s->alpha0_m, any_number());
  r.read("alpha1", &s->alpha1, any_number());
  r.read("alpha2_per_m", &s->alpha2_per_m, any_number());
  r.read("min_depth_m", &s->min_depth_m, positive());
  r.read("max_depth_m", &s->max_depth_m, positive());
  r.read("row_readout_s", &s->row_readout_s, non_negative());
  r.reject_unknown();
  if (!r.clean()) return;  // the rules below assume each value is sane

  require_greater(r, "max_depth_m", s->max_depth_m, "min_depth_m", s->min_depth_m);
  // The axial standard deviation alpha2 z^2 + alpha1 z + alpha0 must stay positive over the
  // working range, or the covariance (and with it the fusion weights) degenerates. Its minimum on
  // [min, max] is at an end or at the vertex of the parabola.
  auto sigma = [s](double z) { return s->alpha2_per_m * z * z + s->alpha1 * z + s->alpha0_m; };
  double z_worst = s->min_depth_m;
  for (double z : {s->max_depth_m, s->alpha2_per_m != 0.0 ? -s->alpha1 / (2.0 * s->alpha2_per_m)
                                                          : s->min_depth_m}) {
    if (z >= s->min_depth_m && z <= s->max_depth_m && sigma(z) < sigma(z_worst)) z_worst = z;
  }
  if (!(sigma(z_worst) > 0.0)) {
    r.fail("alpha0_m", "the axial noise alpha2_per_m z^2 + alpha1 z + alpha0_m must be > 0 over "
                       "[min_depth_m, max_depth_m], but it is " + format_number(sigma(z_worst)) +
                       " m at z = " + format_number(z_worst) + " m");
  }
}

void read_prefilter(TableReader& r, PrefilterConfig* p) {
  r.read("enabled", &p->enabled);
  r.read("gamma", &p->gamma, positive());
  r.read("neighbour_rank", &p->neighbour_rank, at_least(1));
  r.read("window_radius_px", &p->window_radius_px, at_least(1));
  r.reject_unknown();
  if (!r.clean()) return;
  const int side = 2 * p->window_radius_px + 1;
  const int neighbours = side * side - 1;
  if (p->neighbour_rank > neighbours) {
    r.fail("neighbour_rank", "must be <= " + std::to_string(neighbours) +
                                 " (the neighbours in a window of radius window_radius_px = " +
                                 std::to_string(p->window_radius_px) + "), got " +
                                 std::to_string(p->neighbour_rank));
  }
}

void read_fusion(TableReader& r, FusionConfig* f) {
  r.read("chunk_size_m", &f->chunk_size_m, positive());
  r.read("visibility_range_fraction", &f->visibility_range_fraction, open_closed(0.0, 1.0));
  r.read("candidate_radius_px", &f->candidate_radius_px, non_negative());
  r.read("normal_radius_px", &f->normal_radius_px, at_least(1));
  r.read("redundancy_gate", &f->redundancy_gate, non_negative());
  r.read("redundancy_min_merges", &f->redundancy_min_merges, non_negative());
  r.read("deform_points_per_frame", &f->deform_points_per_frame, at_least(1));
  r.read("threads", &f->threads, closed(1, 2));
  r.reject_unknown();
}

void read_postfilter(TableReader& r, PostfilterConfig* p) {
  r.read("enabled", &p->enabled);
  r.reject_unknown();
}

void read_registration(TableReader& r, RegistrationConfig* g) {
  r.read("enabled", &g->enabled);
  r.read("iterations", &g->iterations, non_negative());
  r.read("subsample_px", &g->subsample_px, at_least(1));
  r.read("max_correspondence_m", &g->max_correspondence_m, positive());
  r.read("max_normal_angle_deg", &g->max_normal_angle_deg, open_closed(0.0, 180.0));
  r.read("huber_delta_m", &g->huber_delta_m, positive());
  // A rigid pose has 6 degrees of freedom: fewer pairs cannot determine it.
  r.read("min_correspondences", &g->min_correspondences, at_least(6));
  r.read("degenerate_ratio", &g->degenerate_ratio, closed(0.0, 1.0));
  r.read("model_band_m", &g->model_band_m, positive());
  r.read("tracking_model_band_m", &g->tracking_model_band_m, positive());
  r.read("model_downsample", &g->model_downsample, closed(1, 8));
  r.read("tracking_model_downsample", &g->tracking_model_downsample, closed(1, 8));
  r.read("threads", &g->threads, closed(1, 2));
  r.read("tracking_levels", &g->tracking_levels, closed(1, 8));  // pixel steps grow as 2^level
  r.read("tracking_levels_without_motion", &g->tracking_levels_without_motion, closed(1, 8));
  r.read("tracking_iterations_per_level", &g->tracking_iterations_per_level, non_negative());
  r.read("photometric_weight", &g->photometric_weight, non_negative());
  r.read("tracking_retry_fitness", &g->tracking_retry_fitness, closed(0.0, 1.0));
  r.read("tracking_degenerate_ratio", &g->tracking_degenerate_ratio, closed(0.0, 1.0));
  r.read("motion_prior", &g->motion_prior);
  r.read("model_error_m", &g->model_error_m, closed(0.0, 0.1));
  r.read("motion_prior_min_m", &g->motion_prior_min_m, open_closed(0.0, 1.0));
  r.read("motion_prior_min_deg", &g->motion_prior_min_deg, open_closed(0.0, 90.0));
  r.read("tracking_min_data_share", &g->tracking_min_data_share, closed(0.0, 1.0));
  r.read("tracking_lost_fitness", &g->tracking_lost_fitness, closed(0.0, 1.0));
  r.read("tracking_lost_rmse_m", &g->tracking_lost_rmse_m, positive());
  r.read("tracking_lost_model_fitness", &g->tracking_lost_model_fitness, closed(0.0, 1.0));
  r.read("live_model_reuse_frames", &g->live_model_reuse_frames, closed(1, 30));
  r.read("live_model_reuse_max_m", &g->live_model_reuse_max_m, non_negative());
  r.read("live_model_reuse_max_deg", &g->live_model_reuse_max_deg, closed(0.0, 180.0));
  r.reject_unknown();
}

void read_relocalisation(TableReader& r, RelocalisationConfig* c) {
  r.read("enabled", &c->enabled);
  r.read("keyframe_spacing_m", &c->keyframe_spacing_m, non_negative());
  r.read("keyframe_spacing_deg", &c->keyframe_spacing_deg, closed(0.0, 180.0));
  r.read("max_keyframes", &c->max_keyframes, closed(1, 1024));
  r.read("voxel_m", &c->voxel_m, positive());
  r.read("max_points", &c->max_points, closed(50, 100000));  // fewer carry no shape to match
  r.read("feature_radius_m", &c->feature_radius_m, positive());
  r.read("candidates_per_frame", &c->candidates_per_frame, closed(1, 64));
  r.read("every_n_lost_frames", &c->every_n_lost_frames, closed(1, 1000));
  r.read("sac_iterations", &c->sac_iterations, closed(1, 1000000));
  r.read("sac_inlier_m", &c->sac_inlier_m, positive());
  r.read("sac_inlier_fraction", &c->sac_inlier_fraction, closed(0.0, 1.0));
  r.read("max_speed_m_s", &c->max_speed_m_s, positive());
  r.read("max_turn_deg_s", &c->max_turn_deg_s, positive());
  r.read("ambiguity_rivals", &c->ambiguity_rivals, closed(0, 1000));
  r.read("ambiguity_m", &c->ambiguity_m, positive());
  r.reject_unknown();
}

void read_loop_closure(TableReader& r, LoopClosureConfig* c) {
  r.read("enabled", &c->enabled);
  r.read("keyframe_spacing_m", &c->keyframe_spacing_m, open_closed(0.0, 10.0));
  r.read("keyframe_spacing_deg", &c->keyframe_spacing_deg, open_closed(0.0, 180.0));
  r.read("voxel_m", &c->voxel_m, closed(0.005, 0.5));
  r.read("max_points", &c->max_points, closed(50, 100000));  // fewer carry no shape to match
  r.read("max_cloud_mib", &c->max_cloud_mib, non_negative());
  r.read("cloud_spacing_m", &c->cloud_spacing_m, non_negative());
  r.read("cloud_spacing_deg", &c->cloud_spacing_deg, closed(0.0, 180.0));
  r.read("min_keyframes_back", &c->min_keyframes_back, closed(1, 100000));
  r.read("min_path_m", &c->min_path_m, non_negative());
  r.read("search_radius_m", &c->search_radius_m, positive());
  r.read("max_view_angle_deg", &c->max_view_angle_deg, closed(0.0, 180.0));
  r.read("candidates_per_keyframe", &c->candidates_per_keyframe, closed(0, 64));
  r.read("place_search_every_n_keyframes", &c->place_search_every_n_keyframes, closed(0, 100000));
  r.read("min_overlap", &c->min_overlap, closed(0.0, 1.0));
  r.read("max_correspondence_m", &c->max_correspondence_m, positive());
  r.read("max_rmse_m", &c->max_rmse_m, positive());
  r.read("gate_chi2", &c->gate_chi2, positive());
  r.read("gate_inflation", &c->gate_inflation, closed(1.0, 100.0));
  r.read("model_error_m", &c->model_error_m, closed(0.0, 0.1));
  r.read("loop_loss_scale", &c->loop_loss_scale, positive());
  r.read("loop_chi2_reject", &c->loop_chi2_reject, positive());
  r.read("optimise_window_keyframes", &c->optimise_window_keyframes, closed(0, 1000000));
  r.reject_unknown();
}

void read_pipeline(TableReader& r, PipelineConfig* p) {
  std::string method = to_string(p->method);
  r.read("method", &method, [](const std::string& s) -> std::optional<std::string> {
    Method m;
    if (parse_method(s, &m)) return std::nullopt;
    return "must be one of \"full\", \"ylimaki17\", \"kyostila13\", got \"" + s + "\"";
  });
  Method parsed;
  if (parse_method(method, &parsed)) p->method = parsed;
  r.read("outer_iterations", &p->outer_iterations, non_negative());
  r.read("converged_translation_m", &p->converged_translation_m, non_negative());
  r.read("converged_rotation_deg", &p->converged_rotation_deg, non_negative());
  r.reject_unknown();
}

// An LCM URL is "<provider>://<address>[?options]".
std::optional<std::string> check_lcm_url(const std::string& url) {
  if (url.empty()) return std::string("must not be empty");
  const size_t sep = url.find("://");
  if (sep == std::string::npos || sep == 0) {
    return "must look like \"udpm://239.255.76.67:7667?ttl=0\", got \"" + url + "\"";
  }
  return std::nullopt;
}

void read_lcm(TableReader& r, LcmConfig* l) {
  r.read("url", &l->url, check_lcm_url);
  r.read("key_file", &l->key_file, any_string());
  // Below 0.1 s honest messages arrive stale from a loaded host or one whose NTP is slewing; above
  // two minutes a recorded command stays good for long, and the receivers' replay cache
  // (message_auth.cpp: 65,536 tags for 2 x the skew) no longer holds a rig's ~100 messages a
  // second for that long.
  r.read("max_clock_skew_s", &l->max_clock_skew_s, closed(0.1, 120.0));
  r.reject_unknown();
}

// The frame source specs that open_frame_source understands (drivers/include/.../source_factory.hpp).
std::optional<std::string> check_source(const std::string& spec) {
  const size_t colon = spec.find(':');
  const std::string kind = spec.substr(0, colon);
  const std::string arg = colon == std::string::npos ? "" : spec.substr(colon + 1);
  if (kind == "kinect2") return std::nullopt;  // the serial is optional
  if (kind == "tum" || kind == "synthetic" || kind == "kinect2sim" || kind == "lcmlog") {
    if (!arg.empty()) return std::nullopt;
    return "\"" + kind + ":\" needs an argument after the colon, got \"" + spec + "\"";
  }
  return "must be tum:<folder>, synthetic:<scene>, kinect2[:<serial>], kinect2sim:<scene> or "
         "lcmlog:<file>, got \"" +
         spec + "\"";
}

void read_capture(TableReader& r, CaptureConfig* c) {
  r.read("source", &c->source, check_source);
  r.read("rate_hz", &c->rate_hz, non_negative());
  r.read("loop", &c->loop);
  r.read("kinect2_pipeline", &c->kinect2_pipeline, one_of({"cpu", "opengl", "opencl", "cuda", "depthfuse"}));
  r.read("kinect2_min_depth_m", &c->kinect2_min_depth_m, positive());
  r.read("kinect2_max_depth_m", &c->kinect2_max_depth_m, positive());
  r.read("kinect2_bilateral_filter", &c->kinect2_bilateral_filter);
  r.read("kinect2_edge_aware_filter", &c->kinect2_edge_aware_filter);
  r.read("kinect2_decoder_threads", &c->kinect2_decoder_threads, closed(1, 2));
  r.read("kinect2_stall_timeout_s", &c->kinect2_stall_timeout_s, positive());
  r.reject_unknown();
  if (!r.clean()) return;
  require_greater(r, "kinect2_max_depth_m", c->kinect2_max_depth_m, "kinect2_min_depth_m",
                  c->kinect2_min_depth_m);
}

void read_fusion_daemon(TableReader& r, FusionDaemonConfig* f) {
  // What frames and commands from the bus reach is bounded here, not only by the memory budget:
  // a queue of seconds of frames, images of a real depth sensor, a workspace of a site.
  r.read("queue_capacity_frames", &f->queue_capacity_frames, closed(1, 256));
  r.read("shed_fusion_queue_share", &f->shed_fusion_queue_share, closed(0.0, 1.0));
  r.read("scan_dir", &f->scan_dir, non_empty());
  r.read("memory_budget_mib", &f->memory_budget_mib, positive());
  r.read("evict_distance_m", &f->evict_distance_m, positive());
  r.read("evict_min_age_frames", &f->evict_min_age_frames, non_negative());
  r.read("checkpoint_interval_s", &f->checkpoint_interval_s, positive());
  r.read("frame_log_interval_s", &f->frame_log_interval_s, non_negative());
  r.read("keyframe_every_n_frames", &f->keyframe_every_n_frames, at_least(1));
  r.read("heartbeat_rate_hz", &f->heartbeat_rate_hz, positive());
  r.read("max_frame_width", &f->max_frame_width, closed(1, kMaxFrameSidePx));
  r.read("max_frame_height", &f->max_frame_height, closed(1, kMaxFrameSidePx));
  r.read("workspace_radius_m", &f->workspace_radius_m, open_closed(0.0, 1000.0));
  r.read("min_free_disk_mib", &f->min_free_disk_mib, non_negative());
  r.read("min_scan_interval_s", &f->min_scan_interval_s, closed(0.0, 3600.0));
  r.read("capture_serial", &f->capture_serial, any_string());
  r.reject_unknown();
}

void read_monitor(TableReader& r, MonitorConfig* m) {
  // A forged heartbeat keeps a dead daemon's entry for at most this: not for days.
  r.read("stale_after_s", &m->stale_after_s, open_closed(0.0, 600.0));
  r.read("publish_rate_hz", &m->publish_rate_hz, positive());
  r.read("http", &m->http, any_string());
  r.read("http_allow_remote", &m->http_allow_remote);
  r.read("web_root", &m->web_root, any_string());
  r.reject_unknown();
}

void read_map_preview(TableReader& r, MapPreviewConfig* p) {
  r.read("enabled", &p->enabled);
  r.read("rate_hz", &p->rate_hz, open_closed(0.0, 30.0));
  r.read("cell_size_m", &p->cell_size_m, open_closed(0.0, 0.5));
  // Viewers' snapshot requests make fusion send up to this: at most a gigabit link's worth.
  r.read("max_bytes_per_s", &p->max_bytes_per_s, open_closed(0.0, 1.25e8));
  r.read("target_uncertainty_m", &p->target_uncertainty_m, positive());
  r.read("max_points_per_delta", &p->max_points_per_delta, at_least(1000));
  r.reject_unknown();
}

void read_device(TableReader& r, const SensorModelConfig& sensor_defaults, DeviceCalibration* d) {
  r.require("serial");
  r.read("serial", &d->serial, non_empty());
  CameraIntrinsics& k = d->intrinsics;
  r.read("width", &k.width, at_least(1));
  r.read("height", &k.height, at_least(1));
  r.read("fx", &k.fx, positive());
  r.read("fy", &k.fy, positive());
  r.read("cx", &k.cx, non_negative());
  r.read("cy", &k.cy, non_negative());
  if (const toml::table* t = r.table("sensor")) {
    TableReader sensor(t, r.full_key("sensor"), t->source(), r.diagnostics(), r.trace());
    SensorModelConfig s = sensor_defaults;  // [device.sensor] overrides [sensor] key by key
    read_sensor(sensor, &s);
    d->sensor = s;
  }
  r.reject_unknown();
  if (!r.clean()) return;
  // The principal point lies on the image.
  if (k.cx > k.width - 1) {
    r.fail("cx", "must be <= width - 1 (" + std::to_string(k.width - 1) + "), got " + format_number(k.cx));
  }
  if (k.cy > k.height - 1) {
    r.fail("cy", "must be <= height - 1 (" + std::to_string(k.height - 1) + "), got " + format_number(k.cy));
  }
}

void read_devices(TableReader& top, AppConfig* config) {
  const toml::array* devices = top.array_of_tables("device");
  if (devices == nullptr) return;
  for (size_t i = 0; i < devices->size(); ++i) {
    const toml::table* t = (*devices)[i].as_table();
    const std::string path = "device[" + std::to_string(i) + "]";
    if (t == nullptr) continue;  // array_of_tables() already reported it
    TableReader r(t, path, t->source(), top.diagnostics(), top.trace());
    DeviceCalibration d;
    d.intrinsics = CameraIntrinsics::kinect_v2();
    read_device(r, config->reconstruction.sensor, &d);
    if (!d.serial.empty()) {
      for (size_t j = 0; j < config->devices.size(); ++j) {
        if (config->devices[j].serial == d.serial) {
          r.fail("serial", "duplicate serial \"" + d.serial + "\" (also in device[" +
                               std::to_string(j) + "])");
        }
      }
    }
    config->devices.push_back(std::move(d));
  }
}

Result<AppConfig> parse(const std::string& text, const std::string& origin,
                        std::vector<KeyTrace>* trace) {
  Result<toml::table> parsed = strict_toml::parse_document(text, origin);
  if (!parsed.is_ok()) return parsed.status();
  const toml::table& doc = parsed.value();

  AppConfig config;
  Diagnostics diagnostics(origin);
  TableReader top(&doc, "", doc.source(), &diagnostics, trace);
  // Each section is read from its table, or keeps its defaults when the table is absent.
  auto section = [&](const char* name, auto&& read) {
    const toml::table* t = top.table(name);
    TableReader r(t, name, t != nullptr ? t->source() : doc.source(), &diagnostics, trace);
    read(r);
  };
  ReconstructionConfig& rc = config.reconstruction;
  section("sensor", [&](TableReader& r) { read_sensor(r, &rc.sensor); });
  section("prefilter", [&](TableReader& r) { read_prefilter(r, &rc.prefilter); });
  section("fusion", [&](TableReader& r) { read_fusion(r, &rc.fusion); });
  section("postfilter", [&](TableReader& r) { read_postfilter(r, &rc.postfilter); });
  section("registration", [&](TableReader& r) { read_registration(r, &rc.registration); });
  section("relocalisation", [&](TableReader& r) { read_relocalisation(r, &rc.relocalisation); });
  section("loop_closure", [&](TableReader& r) { read_loop_closure(r, &rc.loop_closure); });
  section("pipeline", [&](TableReader& r) { read_pipeline(r, &rc.pipeline); });
  section("lcm", [&](TableReader& r) { read_lcm(r, &config.lcm); });
  section("capture", [&](TableReader& r) { read_capture(r, &config.capture); });
  section("fusion_daemon", [&](TableReader& r) { read_fusion_daemon(r, &config.fusion); });
  section("monitor", [&](TableReader& r) { read_monitor(r, &config.monitor); });
  section("map_preview", [&](TableReader& r) { read_map_preview(r, &config.map_preview); });
  read_devices(top, &config);
  top.reject_unknown();

  // A daemon is stale when its heartbeat is late; a threshold below the heartbeat period would
  // flag a healthy daemon all the time.
  if (diagnostics.ok()) {
    const double heartbeat_period_s = 1.0 / config.fusion.heartbeat_rate_hz;
    if (!(config.monitor.stale_after_s > heartbeat_period_s)) {
      // Reported at whichever of the two keys the file sets (the threshold if both).
      const toml::table* monitor = doc["monitor"].as_table();
      const toml::table* daemon = doc["fusion_daemon"].as_table();
      TableReader m(monitor, "monitor", doc.source(), &diagnostics, nullptr);
      TableReader f(daemon, "fusion_daemon", doc.source(), &diagnostics, nullptr);
      if (m.has("stale_after_s") || !f.has("heartbeat_rate_hz")) {
        m.fail("stale_after_s", "must be > the heartbeat period 1 / fusion_daemon.heartbeat_rate_hz (" +
                                    format_number(heartbeat_period_s) + " s), got " +
                                    format_number(config.monitor.stale_after_s));
      } else {
        f.fail("heartbeat_rate_hz", "must be > 1 / monitor.stale_after_s (" +
                                        format_number(1.0 / config.monitor.stale_after_s) +
                                        " Hz) or the monitor reports this daemon stale, got " +
                                        format_number(config.fusion.heartbeat_rate_hz));
      }
    }
  }
  DF_RETURN_IF_ERROR(diagnostics.status());
  return config;
}

Result<AppConfig> parse_guarded(const std::string& text, const std::string& origin,
                                std::vector<KeyTrace>* trace) {
  // Nothing may escape the API: an allocation failure or a parser bug becomes a Status.
  try {
    return parse(text, origin, trace);
  } catch (const std::exception& e) {
    return internal_error(origin + ": reading the config failed: " + e.what());
  } catch (...) {
    return internal_error(origin + ": reading the config failed");
  }
}

}  // namespace

bool FusionDaemonConfig::shed_fusion(size_t waiting) const {
  if (shed_fusion_queue_share <= 0) return false;
  const double from =
      std::max(1.0, std::ceil(shed_fusion_queue_share * std::max(1, queue_capacity_frames)));
  return static_cast<double>(waiting) >= from;
}

namespace app_config_detail {
Result<AppConfig> parse_app_config_traced(const std::string& toml_text, const std::string& origin,
                                          std::vector<KeyTrace>* trace) {
  return parse_guarded(toml_text, origin, trace);
}
}  // namespace app_config_detail

Result<AppConfig> parse_app_config(const std::string& toml_text, const std::string& origin) {
  return parse_guarded(toml_text, origin, nullptr);
}

Result<AppConfig> load_app_config(const std::string& path) {
  auto text = read_input_file(path, "config", kMaxConfigBytes);
  if (!text) return text.status();
  Result<AppConfig> config = parse_app_config(*text, path);
  if (config.is_ok()) config->source_path = path;
  return config;
}

}  // namespace depthfuse
