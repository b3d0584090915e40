// The one configuration file of the appliance (config/depthfuse.toml), as structs. Every daemon
// and the CLI read the same file; each takes the sections it needs.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "depthfuse/config.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse {

struct LcmConfig {
  // ttl=0 keeps traffic on this host; recv_buf_size is needed for 512x424 frames (7-14 fragments).
  std::string url = "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304";
  // The rig key that signs and verifies every message (lcm/message_auth.hpp). A file named here
  // that is missing or unusable is an error at start; empty is the explicit choice of no
  // authentication, and the URL is then kept on ttl=0.
  std::string key_file = "/etc/depthfuse/rig.key";
  // How far a signed message's time may lie from the receiver's clock, s, in [0.1, 120].
  double max_clock_skew_s = 2.0;
};

struct CaptureConfig {
  std::string source = "synthetic:corner";  // tum:<folder> | synthetic:<corner|room> | kinect2[:serial] | lcmlog:<file>
  double rate_hz = 30.0;                    // 0 = as fast as possible
  bool loop = false;
  // kinect2 only
  std::string kinect2_pipeline = "depthfuse";  // depthfuse | cpu | opengl | opencl | cuda
  double kinect2_min_depth_m = 0.5;
  double kinect2_max_depth_m = 4.5;
  bool kinect2_bilateral_filter = true;
  bool kinect2_edge_aware_filter = true;
  int kinect2_decoder_threads = 1;           // the depthfuse pipeline's decoder: 1 or 2 threads
  double kinect2_stall_timeout_s = 2.0;     // no frame for this long = stalled: reset and reopen
};

struct FusionDaemonConfig {
  int queue_capacity_frames = 4;            // bounded queue; the oldest frame is dropped when full
  // When the frames waiting fill this share of the queue, the next is tracked but not fused
  // (FrameWork::kTrackOnly), so that fusion falling behind sheds fusion before whole frames. In
  // [0, 1]; 0 = never.
  double shed_fusion_queue_share = 0.5;
  // Whether the frame taken while `waiting` frames wait behind it is to be tracked only: they
  // fill shed_fusion_queue_share of the queue, at least one frame. The daemon's rule, and the
  // benchmark's that plays it.
  bool shed_fusion(size_t waiting) const;
  std::string scan_dir = "/var/lib/depthfuse/scans";  // new scan files, PLY and trajectory on stop
  double memory_budget_mib = 256.0;         // fused map resident in memory
  double evict_distance_m = 1.5;            // chunks within this of the camera are never evicted
  int evict_min_age_frames = 30;            // chunks seen within this many frames go last
  // Full checkpoints (every chunk changed since the last); with the frame log, how much a resume
  // replays at most.
  double checkpoint_interval_s = 30.0;
  // The frame redo log's commits: at most about this much scanning is lost to a crash. 0 = no log
  // (a crash loses what came after the last full checkpoint).
  double frame_log_interval_s = 1.0;
  int keyframe_every_n_frames = 10;         // depth kept for offline refinement
  double heartbeat_rate_hz = 1.0;
  // The largest depth image the daemon takes, px: frames beyond it are refused before decoding.
  int max_frame_width = 640;
  int max_frame_height = 480;
  // The site, m from the world origin: a frame whose pose hint lies beyond it (or is not finite)
  // is tracked without the hint (counted: pose_hints_refused), so that a wrong or forged hint
  // cannot stretch the map.
  double workspace_radius_m = 100.0;
  // A scan starts only with this much free space where scans go, and at most once per
  // min_scan_interval_s: a burst of `scan new` commands must not fill the disk.
  double min_free_disk_mib = 512.0;
  double min_scan_interval_s = 1.0;
  // The one capture the daemon follows, by sensor serial; empty: any. Frames of other serials are
  // dropped before they are decompressed.
  std::string capture_serial;
};

struct MonitorConfig {
  double stale_after_s = 3.0;               // a daemon without a heartbeat for this long is stale
  double publish_rate_hz = 1.0;
  // The operator's page: "ADDR:PORT" to serve it on, empty = off. An address other than loopback
  // needs http_allow_remote.
  std::string http;
  bool http_allow_remote = false;
  std::string web_root;                     // the page's files; empty = the installed ones
};

// The fusion daemon's map preview for viewers (map_delta_t on DEPTHFUSE_MAP).
struct MapPreviewConfig {
  bool enabled = true;
  double rate_hz = 2.0;                     // deltas per second
  double cell_size_m = 0.015;               // one point per cell of this size
  double max_bytes_per_s = 2e6;             // bandwidth cap of the deltas and snapshots
  double target_uncertainty_m = 0.002;      // coverage: the share of points below this
  // Points decimated per delta at most, so that one delta never holds the fusion thread long;
  // the rest of the touched chunks go in the next deltas.
  int max_points_per_delta = 100000;
};

// Calibration of one Kinect, chosen by serial number.
struct DeviceCalibration {
  std::string serial;
  CameraIntrinsics intrinsics;
  std::optional<SensorModelConfig> sensor;  // overrides [sensor] for this device when present
};

struct AppConfig {
  ReconstructionConfig reconstruction;
  LcmConfig lcm;
  CaptureConfig capture;
  FusionDaemonConfig fusion;
  MonitorConfig monitor;
  MapPreviewConfig map_preview;
  std::vector<DeviceCalibration> devices;
  std::string source_path;  // the file it was read from, empty for defaults

  const DeviceCalibration* calibration_for(const std::string& serial) const {
    for (const auto& d : devices)
      if (d.serial == serial) return &d;
    return nullptr;
  }
};

// Reads and validates a TOML config. Errors name the file, the line and the key; an unknown key is
// an error. Keys left out keep their defaults.
Result<AppConfig> load_app_config(const std::string& path);
// The same from text (tests); `origin` names it in messages.
Result<AppConfig> parse_app_config(const std::string& toml_text, const std::string& origin);

}  // namespace depthfuse
