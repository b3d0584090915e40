// The appliance config: defaults, every section, the errors a user gets for a broken file, the
// per-device calibration, and the shipped config/depthfuse.toml (which must equal the defaults).
#include <gtest/gtest.h>

#include <unistd.h>

#include <cstdio>
#include <fstream>
#include <map>
#include <random>
#include <string>
#include <vector>

#include "app_config_trace.hpp"
#include "depthfuse/app_config.hpp"

namespace depthfuse {
namespace {

using app_config_detail::KeyTrace;
using app_config_detail::parse_app_config_traced;

// Field by field, so that a failure names the field.
void expect_sensor_eq(const SensorModelConfig& a, const SensorModelConfig& b) {
  EXPECT_EQ(a.lambda1, b.lambda1);
  EXPECT_EQ(a.lambda2, b.lambda2);
  EXPECT_EQ(a.beta_x_rad, b.beta_x_rad);
  EXPECT_EQ(a.beta_y_rad, b.beta_y_rad);
  EXPECT_EQ(a.alpha0_m, b.alpha0_m);
  EXPECT_EQ(a.alpha1, b.alpha1);
  EXPECT_EQ(a.alpha2_per_m, b.alpha2_per_m);
  EXPECT_EQ(a.min_depth_m, b.min_depth_m);
  EXPECT_EQ(a.max_depth_m, b.max_depth_m);
  EXPECT_EQ(a.row_readout_s, b.row_readout_s);
}

void expect_config_eq(const AppConfig& a, const AppConfig& b) {
  const ReconstructionConfig& ra = a.reconstruction;
  const ReconstructionConfig& rb = b.reconstruction;
  expect_sensor_eq(ra.sensor, rb.sensor);
  EXPECT_EQ(ra.prefilter.enabled, rb.prefilter.enabled);
  EXPECT_EQ(ra.prefilter.gamma, rb.prefilter.gamma);
  EXPECT_EQ(ra.prefilter.neighbour_rank, rb.prefilter.neighbour_rank);
  EXPECT_EQ(ra.prefilter.window_radius_px, rb.prefilter.window_radius_px);
  EXPECT_EQ(ra.fusion.chunk_size_m, rb.fusion.chunk_size_m);
  EXPECT_EQ(ra.fusion.visibility_range_fraction, rb.fusion.visibility_range_fraction);
  EXPECT_EQ(ra.fusion.candidate_radius_px, rb.fusion.candidate_radius_px);
  EXPECT_EQ(ra.fusion.normal_radius_px, rb.fusion.normal_radius_px);
  EXPECT_EQ(ra.fusion.redundancy_gate, rb.fusion.redundancy_gate);
  EXPECT_EQ(ra.fusion.redundancy_min_merges, rb.fusion.redundancy_min_merges);
  EXPECT_EQ(ra.fusion.deform_points_per_frame, rb.fusion.deform_points_per_frame);
  EXPECT_EQ(ra.postfilter.enabled, rb.postfilter.enabled);
  EXPECT_EQ(ra.registration.enabled, rb.registration.enabled);
  EXPECT_EQ(ra.registration.iterations, rb.registration.iterations);
  EXPECT_EQ(ra.registration.subsample_px, rb.registration.subsample_px);
  EXPECT_EQ(ra.registration.max_correspondence_m, rb.registration.max_correspondence_m);
  EXPECT_EQ(ra.registration.max_normal_angle_deg, rb.registration.max_normal_angle_deg);
  EXPECT_EQ(ra.registration.huber_delta_m, rb.registration.huber_delta_m);
  EXPECT_EQ(ra.registration.min_correspondences, rb.registration.min_correspondences);
  EXPECT_EQ(ra.registration.degenerate_ratio, rb.registration.degenerate_ratio);
  EXPECT_EQ(ra.registration.model_band_m, rb.registration.model_band_m);
  EXPECT_EQ(ra.registration.tracking_model_band_m, rb.registration.tracking_model_band_m);
  EXPECT_EQ(ra.registration.model_downsample, rb.registration.model_downsample);
  EXPECT_EQ(ra.registration.tracking_model_downsample, rb.registration.tracking_model_downsample);
  EXPECT_EQ(ra.registration.tracking_levels, rb.registration.tracking_levels);
  EXPECT_EQ(ra.registration.tracking_levels_without_motion,
            rb.registration.tracking_levels_without_motion);
  EXPECT_EQ(ra.registration.tracking_retry_fitness, rb.registration.tracking_retry_fitness);
  EXPECT_EQ(ra.registration.tracking_degenerate_ratio, rb.registration.tracking_degenerate_ratio);
  EXPECT_EQ(ra.registration.tracking_lost_fitness, rb.registration.tracking_lost_fitness);
  EXPECT_EQ(ra.registration.tracking_lost_rmse_m, rb.registration.tracking_lost_rmse_m);
  EXPECT_EQ(ra.registration.tracking_iterations_per_level,
            rb.registration.tracking_iterations_per_level);
  EXPECT_EQ(ra.registration.photometric_weight, rb.registration.photometric_weight);
  EXPECT_EQ(ra.registration.tracking_lost_model_fitness, rb.registration.tracking_lost_model_fitness);
  const RelocalisationConfig &la = ra.relocalisation, &lb = rb.relocalisation;
  EXPECT_EQ(la.enabled, lb.enabled);
  EXPECT_EQ(la.keyframe_spacing_m, lb.keyframe_spacing_m);
  EXPECT_EQ(la.keyframe_spacing_deg, lb.keyframe_spacing_deg);
  EXPECT_EQ(la.max_keyframes, lb.max_keyframes);
  EXPECT_EQ(la.voxel_m, lb.voxel_m);
  EXPECT_EQ(la.max_points, lb.max_points);
  EXPECT_EQ(la.feature_radius_m, lb.feature_radius_m);
  EXPECT_EQ(la.candidates_per_frame, lb.candidates_per_frame);
  EXPECT_EQ(la.every_n_lost_frames, lb.every_n_lost_frames);
  EXPECT_EQ(la.sac_iterations, lb.sac_iterations);
  EXPECT_EQ(la.sac_inlier_m, lb.sac_inlier_m);
  EXPECT_EQ(la.sac_inlier_fraction, lb.sac_inlier_fraction);
  EXPECT_EQ(la.max_speed_m_s, lb.max_speed_m_s);
  EXPECT_EQ(la.max_turn_deg_s, lb.max_turn_deg_s);
  EXPECT_EQ(la.ambiguity_rivals, lb.ambiguity_rivals);
  EXPECT_EQ(la.ambiguity_m, lb.ambiguity_m);
  EXPECT_EQ(ra.pipeline.method, rb.pipeline.method);
  EXPECT_EQ(ra.pipeline.outer_iterations, rb.pipeline.outer_iterations);
  EXPECT_EQ(ra.pipeline.converged_translation_m, rb.pipeline.converged_translation_m);
  EXPECT_EQ(ra.pipeline.converged_rotation_deg, rb.pipeline.converged_rotation_deg);
  EXPECT_EQ(a.lcm.url, b.lcm.url);
  EXPECT_EQ(a.capture.source, b.capture.source);
  EXPECT_EQ(a.capture.rate_hz, b.capture.rate_hz);
  EXPECT_EQ(a.capture.loop, b.capture.loop);
  EXPECT_EQ(a.capture.kinect2_pipeline, b.capture.kinect2_pipeline);
  EXPECT_EQ(a.capture.kinect2_min_depth_m, b.capture.kinect2_min_depth_m);
  EXPECT_EQ(a.capture.kinect2_max_depth_m, b.capture.kinect2_max_depth_m);
  EXPECT_EQ(a.capture.kinect2_bilateral_filter, b.capture.kinect2_bilateral_filter);
  EXPECT_EQ(a.capture.kinect2_edge_aware_filter, b.capture.kinect2_edge_aware_filter);
  EXPECT_EQ(a.capture.kinect2_decoder_threads, b.capture.kinect2_decoder_threads);
  EXPECT_EQ(a.capture.kinect2_stall_timeout_s, b.capture.kinect2_stall_timeout_s);
  EXPECT_EQ(a.fusion.queue_capacity_frames, b.fusion.queue_capacity_frames);
  EXPECT_EQ(a.fusion.shed_fusion_queue_share, b.fusion.shed_fusion_queue_share);
  EXPECT_EQ(a.fusion.scan_dir, b.fusion.scan_dir);
  EXPECT_EQ(a.fusion.memory_budget_mib, b.fusion.memory_budget_mib);
  EXPECT_EQ(a.fusion.evict_distance_m, b.fusion.evict_distance_m);
  EXPECT_EQ(a.fusion.evict_min_age_frames, b.fusion.evict_min_age_frames);
  EXPECT_EQ(a.fusion.checkpoint_interval_s, b.fusion.checkpoint_interval_s);
  EXPECT_EQ(a.fusion.keyframe_every_n_frames, b.fusion.keyframe_every_n_frames);
  EXPECT_EQ(a.fusion.heartbeat_rate_hz, b.fusion.heartbeat_rate_hz);
  EXPECT_EQ(a.monitor.stale_after_s, b.monitor.stale_after_s);
  EXPECT_EQ(a.monitor.publish_rate_hz, b.monitor.publish_rate_hz);
  EXPECT_EQ(a.devices.size(), b.devices.size());
}

// The error text of a config that must be rejected.
std::string error_of(const std::string& text) {
  Result<AppConfig> r = parse_app_config(text, "test.toml");
  EXPECT_FALSE(r.is_ok()) << "accepted:\n" << text;
  if (r.is_ok()) return {};
  EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);
  return r.status().message();
}

AppConfig parsed(const std::string& text) {
  Result<AppConfig> r = parse_app_config(text, "test.toml");
  EXPECT_TRUE(r.is_ok()) << r.status().to_string();
  return r.is_ok() ? r.value() : AppConfig{};
}

TEST(AppConfig, EmptyFileGivesTheDefaults) {
  const AppConfig c = parsed("");
  expect_config_eq(c, AppConfig{});
  EXPECT_TRUE(c.devices.empty());
  EXPECT_TRUE(c.source_path.empty());
  // Comments and empty sections change nothing.
  expect_config_eq(parsed("# nothing\n[sensor]\n[fusion_daemon]\n"), AppConfig{});
}

TEST(AppConfig, ReadsEverySection) {
  const AppConfig c = parsed(R"(
[sensor]
lambda1 = 2.5
lambda2 = 5
beta_x_rad = 0.0027
beta_y_rad = 0.0028
alpha0_m = 0.002
alpha1 = -0.0004
alpha2_per_m = 0.0002
min_depth_m = 0.6
max_depth_m = 4.0
row_readout_s = 0.03

[prefilter]
enabled = false
gamma = 2.0
neighbour_rank = 6
window_radius_px = 2

[fusion]
chunk_size_m = 0.25
visibility_range_fraction = 0.2
candidate_radius_px = 2
normal_radius_px = 3
redundancy_gate = 1.5
redundancy_min_merges = 4
deform_points_per_frame = 5000

[postfilter]
enabled = false

[registration]
enabled = false
iterations = 20
subsample_px = 4
max_correspondence_m = 0.1
max_normal_angle_deg = 45.0
huber_delta_m = 0.01
min_correspondences = 100
degenerate_ratio = 0.01
model_band_m = 0.04
tracking_model_band_m = 0.2
tracking_levels = 2
tracking_levels_without_motion = 4
tracking_iterations_per_level = 5
photometric_weight = 0.5
tracking_retry_fitness = 0.25
tracking_degenerate_ratio = 0.002
tracking_lost_fitness = 0.2
tracking_lost_rmse_m = 0.03
tracking_lost_model_fitness = 0.8

[relocalisation]
enabled = false
keyframe_spacing_m = 0.5
keyframe_spacing_deg = 30
max_keyframes = 8
voxel_m = 0.04
max_points = 400
feature_radius_m = 0.12
candidates_per_frame = 2
every_n_lost_frames = 3
sac_iterations = 100
sac_inlier_m = 0.02
sac_inlier_fraction = 0.5

[pipeline]
method = "ylimaki17"
outer_iterations = 3
converged_translation_m = 1e-3
converged_rotation_deg = 0.1

[lcm]
url = "udpm://239.255.76.68:7668?ttl=1"

[capture]
source = "kinect2:012345678912"
rate_hz = 15
loop = true
kinect2_pipeline = "opengl"
kinect2_min_depth_m = 0.7
kinect2_max_depth_m = 3.5
kinect2_bilateral_filter = false
kinect2_edge_aware_filter = false
kinect2_decoder_threads = 2
kinect2_stall_timeout_s = 5.0

[fusion_daemon]
queue_capacity_frames = 8
shed_fusion_queue_share = 0.25
scan_dir = "/srv/scans"
memory_budget_mib = 512
evict_distance_m = 8.0
evict_min_age_frames = 90
checkpoint_interval_s = 60
keyframe_every_n_frames = 5
heartbeat_rate_hz = 2.0

[monitor]
stale_after_s = 5.0
publish_rate_hz = 0.5
)");
  const SensorModelConfig& s = c.reconstruction.sensor;
  EXPECT_EQ(s.lambda1, 2.5);
  EXPECT_EQ(s.lambda2, 5.0);  // an integer where a float is expected
  EXPECT_EQ(s.beta_x_rad, 0.0027);
  EXPECT_EQ(s.beta_y_rad, 0.0028);
  EXPECT_EQ(s.alpha0_m, 0.002);
  EXPECT_EQ(s.row_readout_s, 0.03);
  EXPECT_EQ(s.alpha1, -0.0004);
  EXPECT_EQ(s.alpha2_per_m, 0.0002);
  EXPECT_EQ(s.min_depth_m, 0.6);
  EXPECT_EQ(s.max_depth_m, 4.0);
  const PrefilterConfig& p = c.reconstruction.prefilter;
  EXPECT_FALSE(p.enabled);
  EXPECT_EQ(p.gamma, 2.0);
  EXPECT_EQ(p.neighbour_rank, 6);
  EXPECT_EQ(p.window_radius_px, 2);
  const FusionConfig& f = c.reconstruction.fusion;
  EXPECT_EQ(f.chunk_size_m, 0.25);
  EXPECT_EQ(f.visibility_range_fraction, 0.2);
  EXPECT_EQ(f.candidate_radius_px, 2);
  EXPECT_EQ(f.normal_radius_px, 3);
  EXPECT_EQ(f.redundancy_gate, 1.5);
  EXPECT_EQ(f.redundancy_min_merges, 4);
  EXPECT_EQ(f.deform_points_per_frame, 5000);
  EXPECT_FALSE(c.reconstruction.postfilter.enabled);
  const RegistrationConfig& g = c.reconstruction.registration;
  EXPECT_FALSE(g.enabled);
  EXPECT_EQ(g.iterations, 20);
  EXPECT_EQ(g.subsample_px, 4);
  EXPECT_EQ(g.max_correspondence_m, 0.1);
  EXPECT_EQ(g.max_normal_angle_deg, 45.0);
  EXPECT_EQ(g.huber_delta_m, 0.01);
  EXPECT_EQ(g.min_correspondences, 100);
  EXPECT_EQ(g.degenerate_ratio, 0.01);
  EXPECT_EQ(g.model_band_m, 0.04);
  EXPECT_EQ(g.tracking_model_band_m, 0.2);
  EXPECT_EQ(g.tracking_levels, 2);
  EXPECT_EQ(g.tracking_levels_without_motion, 4);
  EXPECT_EQ(g.tracking_iterations_per_level, 5);
  EXPECT_EQ(g.photometric_weight, 0.5);
  EXPECT_EQ(g.tracking_retry_fitness, 0.25);
  EXPECT_EQ(g.tracking_degenerate_ratio, 0.002);
  EXPECT_EQ(g.tracking_lost_fitness, 0.2);
  EXPECT_EQ(g.tracking_lost_rmse_m, 0.03);
  EXPECT_EQ(g.tracking_lost_model_fitness, 0.8);
  const RelocalisationConfig& l = c.reconstruction.relocalisation;
  EXPECT_FALSE(l.enabled);
  EXPECT_EQ(l.keyframe_spacing_m, 0.5);
  EXPECT_EQ(l.keyframe_spacing_deg, 30.0);
  EXPECT_EQ(l.max_keyframes, 8);
  EXPECT_EQ(l.voxel_m, 0.04);
  EXPECT_EQ(l.max_points, 400);
  EXPECT_EQ(l.feature_radius_m, 0.12);
  EXPECT_EQ(l.candidates_per_frame, 2);
  EXPECT_EQ(l.every_n_lost_frames, 3);
  EXPECT_EQ(l.sac_iterations, 100);
  EXPECT_EQ(l.sac_inlier_m, 0.02);
  EXPECT_EQ(l.sac_inlier_fraction, 0.5);
  const PipelineConfig& pl = c.reconstruction.pipeline;
  EXPECT_EQ(pl.method, Method::kYlimaki17);
  EXPECT_EQ(pl.outer_iterations, 3);
  EXPECT_EQ(pl.converged_translation_m, 1e-3);
  EXPECT_EQ(pl.converged_rotation_deg, 0.1);
  EXPECT_EQ(c.lcm.url, "udpm://239.255.76.68:7668?ttl=1");
  EXPECT_EQ(c.capture.source, "kinect2:012345678912");
  EXPECT_EQ(c.capture.rate_hz, 15.0);
  EXPECT_TRUE(c.capture.loop);
  EXPECT_EQ(c.capture.kinect2_pipeline, "opengl");
  EXPECT_EQ(c.capture.kinect2_min_depth_m, 0.7);
  EXPECT_EQ(c.capture.kinect2_max_depth_m, 3.5);
  EXPECT_FALSE(c.capture.kinect2_bilateral_filter);
  EXPECT_FALSE(c.capture.kinect2_edge_aware_filter);
  EXPECT_EQ(c.capture.kinect2_decoder_threads, 2);
  EXPECT_EQ(c.capture.kinect2_stall_timeout_s, 5.0);
  EXPECT_EQ(c.fusion.queue_capacity_frames, 8);
  EXPECT_EQ(c.fusion.shed_fusion_queue_share, 0.25);
  EXPECT_TRUE(c.fusion.shed_fusion(2) && !c.fusion.shed_fusion(1));  // a quarter of 8
  EXPECT_EQ(c.fusion.scan_dir, "/srv/scans");
  EXPECT_EQ(c.fusion.memory_budget_mib, 512.0);
  EXPECT_EQ(c.fusion.evict_distance_m, 8.0);
  EXPECT_EQ(c.fusion.evict_min_age_frames, 90);
  EXPECT_EQ(c.fusion.checkpoint_interval_s, 60.0);
  EXPECT_EQ(c.fusion.keyframe_every_n_frames, 5);
  EXPECT_EQ(c.fusion.heartbeat_rate_hz, 2.0);
  EXPECT_EQ(c.monitor.stale_after_s, 5.0);
  EXPECT_EQ(c.monitor.publish_rate_hz, 0.5);
}

// A frame's fusion is shed when the frames waiting fill the share of the queue, one at least;
// never with a share of 0.
TEST(AppConfig, ShedFusionFromAShareOfTheQueue) {
  FusionDaemonConfig f;
  // Shed from `from` frames waiting on, not below.
  auto sheds_from = [&](size_t from) {
    return f.shed_fusion(from) && f.shed_fusion(from + 10) && (from == 0 || !f.shed_fusion(from - 1));
  };
  EXPECT_TRUE(sheds_from(2));  // half of 4
  f.queue_capacity_frames = 64;
  EXPECT_TRUE(sheds_from(32));
  f.queue_capacity_frames = 1;
  EXPECT_TRUE(sheds_from(1));
  EXPECT_FALSE(f.shed_fusion(0));  // at least one frame waits
  f.queue_capacity_frames = 5;
  f.shed_fusion_queue_share = 0.3;
  EXPECT_TRUE(sheds_from(2));  // 1.5 frames: from the second
  f.shed_fusion_queue_share = 0.0;
  for (size_t waiting : {0, 1, 5, 256}) EXPECT_FALSE(f.shed_fusion(waiting)) << waiting;
}

TEST(AppConfig, KeysLeftOutKeepTheirDefaults) {
  const AppConfig c = parsed("[fusion_daemon]\nmemory_budget_mib = 100\n");
  EXPECT_EQ(c.fusion.memory_budget_mib, 100.0);
  AppConfig expected;
  expected.fusion.memory_budget_mib = 100.0;
  expect_config_eq(c, expected);
}

TEST(AppConfig, DottedKeysAndInlineTablesAreTheSameAsSections) {
  EXPECT_EQ(parsed("fusion.chunk_size_m = 0.75\n").reconstruction.fusion.chunk_size_m, 0.75);
  EXPECT_EQ(parsed("monitor = { publish_rate_hz = 4.0 }\n").monitor.publish_rate_hz, 4.0);
}

TEST(AppConfig, EveryMethodName) {
  EXPECT_EQ(parsed("[pipeline]\nmethod = \"full\"\n").reconstruction.pipeline.method, Method::kFull);
  EXPECT_EQ(parsed("[pipeline]\nmethod = \"ylimaki17\"\n").reconstruction.pipeline.method,
            Method::kYlimaki17);
  EXPECT_EQ(parsed("[pipeline]\nmethod = \"kyostila13\"\n").reconstruction.pipeline.method,
            Method::kKyostila13);
  const std::string e = error_of("[pipeline]\nmethod = \"fast\"\n");
  EXPECT_NE(e.find("test.toml:2: pipeline.method: must be one of"), std::string::npos) << e;
  EXPECT_NE(e.find("got \"fast\""), std::string::npos) << e;
}

TEST(AppConfig, UnknownKeyIsAnErrorWithItsLine) {
  const std::string e = error_of("[sensor]\nlambda1 = 3.0\nlamda2 = 4.0\n");
  EXPECT_NE(e.find("test.toml:3: sensor.lamda2: unknown key"), std::string::npos) << e;
  EXPECT_NE(e.find("did you mean \"lambda2\""), std::string::npos) << e;
}

TEST(AppConfig, UnknownSectionIsAnErrorWithItsLine) {
  const std::string e = error_of("# config\n\n[fusoin]\nchunk_size_m = 0.5\n");
  EXPECT_NE(e.find("test.toml:3: fusoin: unknown section (did you mean \"fusion\"?)"),
            std::string::npos)
      << e;
  // A key at the top level, outside every section.
  const std::string top = error_of("memory_budget_mib = 5\n");
  EXPECT_NE(top.find("test.toml:1: memory_budget_mib: unknown key"), std::string::npos) << top;
  // Unknown keys inside a device and its sensor sub-table.
  const std::string dev =
      error_of("[[device]]\nserial = \"a\"\nfocal = 3\n[device.sensor]\nlambda3 = 1\n");
  EXPECT_NE(dev.find("test.toml:3: device[0].focal: unknown key"), std::string::npos) << dev;
  EXPECT_NE(dev.find("test.toml:5: device[0].sensor.lambda3: unknown key"), std::string::npos) << dev;
}

TEST(AppConfig, WrongTypesAreErrors) {
  struct Case {
    std::string text;
    std::string expected;
  };
  const std::vector<Case> cases = {
      {"[prefilter]\ngamma = \"1.83\"\n",
       "test.toml:2: prefilter.gamma: expected a number, got a string"},
      {"[registration]\niterations = 10.5\n",
       "test.toml:2: registration.iterations: expected an integer, got a floating-point number"},
      {"[registration]\niterations = 10.0\n",
       "registration.iterations: expected an integer, got a floating-point number"},
      {"[postfilter]\nenabled = 1\n",
       "test.toml:2: postfilter.enabled: expected a boolean (true or false), got an integer"},
      {"[lcm]\nurl = 7667\n", "test.toml:2: lcm.url: expected a string, got an integer"},
      {"sensor = 3\n", "test.toml:1: sensor: expected a table, got an integer"},
      {"[capture]\nrate_hz = [30]\n", "capture.rate_hz: expected a number, got an array"},
      {"[monitor]\nstale_after_s = 1979-05-27\n", "monitor.stale_after_s: expected a number, got a date"},
      {"[device]\nserial = \"a\"\n", "device: expected an array of tables ([[device]]), got a table"},
      {"[[device]]\nserial = 12\n", "test.toml:2: device[0].serial: expected a string, got an integer"},
      {"[fusion_daemon]\nqueue_capacity_frames = 4294967296\n",
       "fusion_daemon.queue_capacity_frames: out of range, got 4294967296"},
  };
  for (const Case& c : cases) {
    const std::string e = error_of(c.text);
    EXPECT_NE(e.find(c.expected), std::string::npos) << "config:\n" << c.text << "error:\n" << e;
  }
}

TEST(AppConfig, OutOfRangeValuesAreErrors) {
  struct Case {
    std::string section, key, value, expected;
  };
  const std::vector<Case> cases = {
      {"fusion_daemon", "memory_budget_mib", "-5", "must be > 0, got -5"},
      {"fusion_daemon", "memory_budget_mib", "0", "must be > 0, got 0"},
      {"fusion_daemon", "queue_capacity_frames", "0", "must be in [1, 256], got 0"},
      {"fusion_daemon", "shed_fusion_queue_share", "1.5", "must be in [0, 1], got 1.5"},
      {"fusion_daemon", "scan_dir", "\"\"", "must not be empty"},
      {"fusion_daemon", "checkpoint_interval_s", "0.0", "must be > 0, got 0"},
      {"fusion_daemon", "evict_distance_m", "-1", "must be > 0, got -1"},
      {"fusion_daemon", "evict_min_age_frames", "-1", "must be >= 0, got -1"},
      {"fusion_daemon", "keyframe_every_n_frames", "0", "must be >= 1, got 0"},
      {"fusion_daemon", "heartbeat_rate_hz", "0", "must be > 0, got 0"},
      {"sensor", "lambda1", "0", "must be > 0, got 0"},
      {"sensor", "lambda2", "-1.5", "must be > 0, got -1.5"},
      {"sensor", "beta_x_rad", "-0.001", "must be >= 0, got -0.001"},
      {"sensor", "min_depth_m", "0", "must be > 0, got 0"},
      {"sensor", "alpha0_m", "nan", "must be a finite number, got nan"},
      {"sensor", "alpha1", "inf", "must be a finite number, got inf"},
      {"prefilter", "gamma", "0", "must be > 0, got 0"},
      {"capture", "kinect2_decoder_threads", "3", "must be in [1, 2], got 3"},
      {"prefilter", "neighbour_rank", "0", "must be >= 1, got 0"},
      {"prefilter", "window_radius_px", "0", "must be >= 1, got 0"},
      {"fusion", "chunk_size_m", "0", "must be > 0, got 0"},
      {"fusion", "visibility_range_fraction", "1.5", "must be in (0, 1], got 1.5"},
      {"fusion", "candidate_radius_px", "-1", "must be >= 0, got -1"},
      {"fusion", "normal_radius_px", "0", "must be >= 1, got 0"},
      {"fusion", "redundancy_gate", "-1", "must be >= 0, got -1"},
      {"fusion", "redundancy_min_merges", "-2", "must be >= 0, got -2"},
      {"fusion", "deform_points_per_frame", "0", "must be >= 1, got 0"},
      {"registration", "iterations", "-1", "must be >= 0, got -1"},
      {"registration", "subsample_px", "0", "must be >= 1, got 0"},
      {"registration", "max_correspondence_m", "0", "must be > 0, got 0"},
      {"registration", "max_normal_angle_deg", "190", "must be in (0, 180], got 190"},
      {"registration", "huber_delta_m", "-0.1", "must be > 0, got -0.1"},
      {"registration", "min_correspondences", "5", "must be >= 6, got 5"},
      {"registration", "degenerate_ratio", "-0.1", "must be in [0, 1], got -0.1"},
      {"registration", "degenerate_ratio", "2", "must be in [0, 1], got 2"},
      {"registration", "tracking_model_band_m", "0", "must be > 0, got 0"},
      {"registration", "tracking_levels", "0", "must be in [1, 8], got 0"},
      {"registration", "tracking_levels", "9", "must be in [1, 8], got 9"},
      {"registration", "tracking_levels_without_motion", "0", "must be in [1, 8], got 0"},
      {"registration", "tracking_iterations_per_level", "-2", "must be >= 0, got -2"},
      {"registration", "photometric_weight", "-0.1", "must be >= 0, got -0.1"},
      {"registration", "tracking_retry_fitness", "1.5", "must be in [0, 1], got 1.5"},
      {"registration", "live_model_reuse_frames", "0", "must be in [1, 30], got 0"},
      {"registration", "live_model_reuse_max_m", "-0.01", "must be >= 0, got -0.01"},
      {"registration", "live_model_reuse_max_deg", "200", "must be in [0, 180], got 200"},
      {"pipeline", "outer_iterations", "-1", "must be >= 0, got -1"},
      {"pipeline", "converged_translation_m", "-1e-3", "must be >= 0, got -0.001"},
      {"pipeline", "converged_rotation_deg", "-1", "must be >= 0, got -1"},
      {"lcm", "url", "\"\"", "must not be empty"},
      {"lcm", "url", "\"239.255.76.67:7667\"", "must look like"},
      {"capture", "source", "\"\"", "must be tum:<folder>"},
      {"capture", "source", "\"kinect:123\"", "must be tum:<folder>"},
      {"capture", "source", "\"tum:\"", "\"tum:\" needs an argument"},
      {"capture", "rate_hz", "-30", "must be >= 0, got -30"},
      {"capture", "kinect2_pipeline", "\"vulkan\"", "must be one of \"cpu\", \"opengl\""},
      {"capture", "kinect2_min_depth_m", "0", "must be > 0, got 0"},
      {"capture", "kinect2_stall_timeout_s", "0", "must be > 0, got 0"},
      {"monitor", "stale_after_s", "0", "must be in (0, 600], got 0"},
      {"monitor", "publish_rate_hz", "-1", "must be > 0, got -1"},
      // Issue 36: what a stranger's traffic reaches is bounded on both sides.
      {"lcm", "max_clock_skew_s", "1e7", "must be in [0.1, 120], got 10000000"},
      {"lcm", "max_clock_skew_s", "1e30", "must be in [0.1, 120], got 1e+30"},
      {"lcm", "max_clock_skew_s", "0.01", "must be in [0.1, 120], got 0.01"},
      {"fusion_daemon", "queue_capacity_frames", "100000", "must be in [1, 256], got 100000"},
      {"fusion_daemon", "max_frame_width", "65535", "must be in [1, 4096], got 65535"},
      {"fusion_daemon", "max_frame_height", "0", "must be in [1, 4096], got 0"},
      {"fusion_daemon", "workspace_radius_m", "0", "must be in (0, 1000], got 0"},
      {"fusion_daemon", "workspace_radius_m", "1e6", "must be in (0, 1000], got 1000000"},
      {"fusion_daemon", "min_scan_interval_s", "1e9", "must be in [0, 3600], got 1000000000"},
      {"monitor", "stale_after_s", "1e9", "must be in (0, 600], got 1000000000"},
      {"map_preview", "max_bytes_per_s", "1e12", "must be in (0, 125000000], got 1e+12"},
  };
  for (const Case& c : cases) {
    const std::string text = "# a comment\n[" + c.section + "]\n" + c.key + " = " + c.value + "\n";
    const std::string e = error_of(text);
    const std::string expected = "test.toml:3: " + c.section + "." + c.key + ": " + c.expected;
    EXPECT_NE(e.find(expected), std::string::npos) << "expected: " << expected << "\ngot: " << e;
  }
  // Exactly the message format of the brief, nothing more.
  EXPECT_EQ(error_of("[fusion_daemon]\nmemory_budget_mib = -5\n"),
            "test.toml:2: fusion_daemon.memory_budget_mib: must be > 0, got -5");
}

TEST(AppConfig, RulesAcrossKeys) {
  std::string e = error_of("[sensor]\nmin_depth_m = 2.0\nmax_depth_m = 1.0\n");
  EXPECT_NE(e.find("test.toml:3: sensor.max_depth_m: must be > min_depth_m (2), got 1"),
            std::string::npos)
      << e;
  e = error_of("[capture]\nkinect2_min_depth_m = 4.5\n");
  EXPECT_NE(e.find("capture.kinect2_max_depth_m: must be > kinect2_min_depth_m (4.5), got 4.5"),
            std::string::npos)
      << e;
  // 4th nearest neighbour needs at least 4 neighbours in the window: radius 1 has 8.
  e = error_of("[prefilter]\nneighbour_rank = 9\n");
  EXPECT_NE(e.find("test.toml:2: prefilter.neighbour_rank: must be <= 8"), std::string::npos) << e;
  EXPECT_TRUE(parse_app_config("[prefilter]\nneighbour_rank = 9\nwindow_radius_px = 2\n", "t").is_ok());
  // An axial noise model that goes negative inside the working range.
  e = error_of("[sensor]\nalpha0_m = 0.0\nalpha1 = -0.001\nalpha2_per_m = 0.0\n");
  EXPECT_NE(e.find("test.toml:2: sensor.alpha0_m: the axial noise"), std::string::npos) << e;
  // ... including at the vertex of the parabola, between min and max depth.
  e = error_of("[sensor]\nalpha0_m = 0.001\nalpha1 = -0.004\nalpha2_per_m = 0.002\n");
  EXPECT_NE(e.find("at z = 1 m"), std::string::npos) << e;
  // A stale threshold shorter than the heartbeat period.
  e = error_of("[monitor]\nstale_after_s = 0.5\n");
  EXPECT_NE(e.find("test.toml:2: monitor.stale_after_s: must be > the heartbeat period"),
            std::string::npos)
      << e;
  e = error_of("[fusion_daemon]\nheartbeat_rate_hz = 0.2\n");
  EXPECT_NE(e.find("test.toml:2: fusion_daemon.heartbeat_rate_hz: must be > 1 / monitor.stale_after_s"),
            std::string::npos)
      << e;
}

TEST(AppConfig, AllProblemsAreReportedTogether) {
  const std::string e = error_of("[fusion]\nchunk_size_m = -1\n[monitor]\npublish_rate_hz = 0\nbogus = 1\n");
  EXPECT_NE(e.find("test.toml:2: fusion.chunk_size_m"), std::string::npos) << e;
  EXPECT_NE(e.find("test.toml:4: monitor.publish_rate_hz"), std::string::npos) << e;
  EXPECT_NE(e.find("test.toml:5: monitor.bogus: unknown key"), std::string::npos) << e;
  // In the order of the file, although sections are checked in another order.
  const std::string out_of_order = error_of("[monitor]\npublish_rate_hz = 0\n[sensor]\nlambda1 = 0\n");
  EXPECT_LT(out_of_order.find("test.toml:2:"), out_of_order.find("test.toml:4:")) << out_of_order;
}

TEST(AppConfig, SyntaxErrorNamesTheLine) {
  std::string e;
  EXPECT_NO_THROW(e = error_of("[sensor]\nlambda1 = 3.0\n[fusion\nchunk_size_m = 1\n"));
  EXPECT_NE(e.find("test.toml:3: TOML syntax error"), std::string::npos) << e;
  EXPECT_NO_THROW(e = error_of("[sensor]\nlambda1 = = 3\n"));
  EXPECT_NE(e.find("test.toml:2: TOML syntax error"), std::string::npos) << e;
  // A key given twice is a TOML error, not a silent override.
  EXPECT_NO_THROW(e = error_of("[sensor]\nlambda1 = 3.0\nlambda1 = 4.0\n"));
  EXPECT_NE(e.find("test.toml:3: TOML syntax error"), std::string::npos) << e;
}

TEST(AppConfig, GarbageNeverThrows) {
  std::mt19937 rng(1234);
  const std::string seed = "[sensor]\nlambda1 = 3.0\n[[device]]\nserial = \"x\"\nfx = 365\n";
  for (int i = 0; i < 300; ++i) {
    std::string text = seed;
    // Flip, insert or delete a few bytes at random.
    for (int k = 0; k < 4; ++k) {
      const size_t pos = rng() % (text.size() + 1);
      const char byte = static_cast<char>(rng() % 256);
      switch (rng() % 3) {
        case 0: if (pos < text.size()) text[pos] = byte; break;
        case 1: text.insert(text.begin() + pos, byte); break;
        default: if (pos < text.size()) text.erase(pos, 1); break;
      }
    }
    EXPECT_NO_THROW({
      Result<AppConfig> r = parse_app_config(text, "fuzz.toml");
      if (!r.is_ok()) {
        EXPECT_EQ(r.status().message().rfind("fuzz.toml", 0), 0u) << r.status().message();
      }
    });
  }
}

TEST(AppConfig, DeviceCalibrationBySerial) {
  const AppConfig c = parsed(R"(
[sensor]
lambda1 = 2.0
alpha0_m = 0.002

[[device]]
serial = "003726334247"
fx = 366.1
fy = 366.3
cx = 258.2
cy = 204.9

[[device]]
serial = "501512442342"
width = 512
height = 424
fx = 364.0
fy = 364.5
cx = 254.0
cy = 210.0
[device.sensor]
lambda2 = 6.0
)");
  ASSERT_EQ(c.devices.size(), 2u);
  EXPECT_EQ(c.calibration_for("unknown-serial"), nullptr);
  EXPECT_EQ(c.calibration_for(""), nullptr);

  const DeviceCalibration* a = c.calibration_for("003726334247");
  ASSERT_NE(a, nullptr);
  EXPECT_EQ(a->intrinsics.fx, 366.1);
  EXPECT_EQ(a->intrinsics.fy, 366.3);
  EXPECT_EQ(a->intrinsics.cx, 258.2);
  EXPECT_EQ(a->intrinsics.cy, 204.9);
  EXPECT_EQ(a->intrinsics.width, 512);   // left out: the Kinect V2 size
  EXPECT_EQ(a->intrinsics.height, 424);
  EXPECT_FALSE(a->sensor.has_value());   // no [device.sensor]: [sensor] applies

  const DeviceCalibration* b = c.calibration_for("501512442342");
  ASSERT_NE(b, nullptr);
  EXPECT_EQ(b->intrinsics.fx, 364.0);
  ASSERT_TRUE(b->sensor.has_value());
  // The override starts from [sensor] of this file and changes only the keys it names.
  EXPECT_EQ(b->sensor->lambda2, 6.0);
  EXPECT_EQ(b->sensor->lambda1, 2.0);
  EXPECT_EQ(b->sensor->alpha0_m, 0.002);
  EXPECT_EQ(b->sensor->max_depth_m, SensorModelConfig{}.max_depth_m);
}

TEST(AppConfig, DeviceErrors) {
  std::string e = error_of("[[device]]\nfx = 365\n");
  EXPECT_NE(e.find("test.toml:1: device[0].serial: missing; this key is required"), std::string::npos) << e;
  e = error_of("[[device]]\nserial = \"a\"\n[[device]]\nserial = \"b\"\n[[device]]\nserial = \"a\"\n");
  EXPECT_NE(e.find("test.toml:6: device[2].serial: duplicate serial \"a\" (also in device[0])"),
            std::string::npos)
      << e;
  e = error_of("[[device]]\nserial = \"a\"\nfx = -365\n");
  EXPECT_NE(e.find("test.toml:3: device[0].fx: must be > 0, got -365"), std::string::npos) << e;
  e = error_of("[[device]]\nserial = \"a\"\ncx = 600\n");
  EXPECT_NE(e.find("test.toml:3: device[0].cx: must be <= width - 1 (511), got 600"), std::string::npos) << e;
  e = error_of("[[device]]\nserial = \"a\"\n[device.sensor]\nmin_depth_m = 5.0\n");
  EXPECT_NE(e.find("device[0].sensor.max_depth_m: must be > min_depth_m"), std::string::npos) << e;
  e = error_of("[[device]]\nserial = \"\"\n");
  EXPECT_NE(e.find("test.toml:2: device[0].serial: must not be empty"), std::string::npos) << e;
}

// A file on disk, removed at the end of the test.
class TempFile {
 public:
  explicit TempFile(const std::string& text) {
    char name[] = "/tmp/depthfuse-config-XXXXXX";
    const int fd = mkstemp(name);
    EXPECT_GE(fd, 0);
    if (fd >= 0) {
      EXPECT_EQ(write(fd, text.data(), text.size()), static_cast<ssize_t>(text.size()));
      close(fd);
    }
    path_ = name;
  }
  ~TempFile() { std::remove(path_.c_str()); }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

TEST(AppConfig, LoadFromFile) {
  TempFile file("[fusion_daemon]\nmemory_budget_mib = 64\n");
  Result<AppConfig> c = load_app_config(file.path());
  ASSERT_TRUE(c.is_ok()) << c.status().to_string();
  EXPECT_EQ(c->fusion.memory_budget_mib, 64.0);
  EXPECT_EQ(c->source_path, file.path());

  TempFile bad("[fusion_daemon]\nmemory_budget_mib = -5\n");
  Result<AppConfig> b = load_app_config(bad.path());
  ASSERT_FALSE(b.is_ok());
  EXPECT_EQ(b.status().message(), bad.path() + ":2: fusion_daemon.memory_budget_mib: must be > 0, got -5");

  Result<AppConfig> missing = load_app_config("/nonexistent/depthfuse.toml");
  ASSERT_FALSE(missing.is_ok());
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
  EXPECT_NE(missing.status().message().find("/nonexistent/depthfuse.toml"), std::string::npos);

  Result<AppConfig> dir = load_app_config("/tmp");
  ASSERT_FALSE(dir.is_ok());
  EXPECT_NE(dir.status().message().find("not a regular file"), std::string::npos);
}

std::vector<KeyTrace> trace_of(const std::string& text, const std::string& origin) {
  std::vector<KeyTrace> trace;
  Result<AppConfig> r = parse_app_config_traced(text, origin, &trace);
  EXPECT_TRUE(r.is_ok()) << r.status().to_string();
  return trace;
}

std::string read_text(const std::string& path) {
  std::ifstream in(path);
  EXPECT_TRUE(in.good()) << path;
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// The shipped file documents every key with its default: it must parse, give every key the loader
// knows, and each value must equal the default in the structs (so the docs cannot drift).
TEST(ShippedConfig, ParsesAndEqualsTheDefaults) {
  Result<AppConfig> shipped = load_app_config(DEPTHFUSE_SHIPPED_CONFIG);
  ASSERT_TRUE(shipped.is_ok()) << shipped.status().to_string();
  expect_config_eq(shipped.value(), AppConfig{});
  EXPECT_TRUE(shipped->devices.empty()) << "the [[device]] example must stay commented out";

  const std::vector<KeyTrace> defaults = trace_of("", "defaults");
  const std::vector<KeyTrace> file = trace_of(read_text(DEPTHFUSE_SHIPPED_CONFIG), "shipped");
  ASSERT_GT(defaults.size(), 40u);
  std::map<std::string, const KeyTrace*> in_file;
  for (const KeyTrace& t : file) in_file[t.key] = &t;
  for (const KeyTrace& d : defaults) {
    ASSERT_EQ(in_file.count(d.key), 1u) << d.key;
    const KeyTrace& f = *in_file[d.key];
    EXPECT_TRUE(f.from_file) << "config/depthfuse.toml does not set " << d.key;
    EXPECT_EQ(f.value, d.value) << "config/depthfuse.toml: " << d.key << " differs from the default";
  }
}

// The commented [[device]] example of the shipped file is valid once uncommented.
TEST(ShippedConfig, DeviceExampleIsValid) {
  std::string text = read_text(DEPTHFUSE_SHIPPED_CONFIG);
  const size_t start = text.find("# [[device]]");
  ASSERT_NE(start, std::string::npos) << "config/depthfuse.toml has no [[device]] example";
  // Uncomment the example block: the lines starting with "# " from the marker to the file's end
  // that look like TOML (a table header or key = value).
  std::string example;
  std::istringstream lines(text.substr(start));
  std::string line;
  while (std::getline(lines, line)) {
    if (line.rfind("# ", 0) != 0) break;
    const std::string body = line.substr(2);
    if (!body.empty() && (body[0] == '[' || body.find(" = ") != std::string::npos)) example += body + "\n";
  }
  Result<AppConfig> c = parse_app_config(text + "\n" + example, "shipped+example");
  ASSERT_TRUE(c.is_ok()) << c.status().to_string() << "\nexample:\n" << example;
  ASSERT_FALSE(c->devices.empty());
  EXPECT_NE(c->calibration_for(c->devices[0].serial), nullptr);
}

}  // namespace
}  // namespace depthfuse
