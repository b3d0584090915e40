// The seam between the fusion daemon and durable storage: the daemon tells a CheckpointSink when
// a scan begins, around every frame, when a checkpoint is due (periodic, or the operator's
// 'checkpoint now') and when the scan ends. The SQLite scan store plugs in here by implementing
// this interface (SqliteCheckpointSink, sqlite_checkpoint_sink.hpp, on store::ScanRecorder:
// create or resume / prepare_frame / record_frame / checkpoint / finish / export_cloud);
// NullCheckpointSink keeps nothing and the scan is saved as PLY + TUM trajectory on stop only.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "depthfuse/app_config.hpp"
#include "depthfuse/frame_path.hpp"
#include "depthfuse/pipeline.hpp"
#include "depthfuse/ply.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::fusiond {

struct ScanContext {
  std::string scan_id;
  std::string scan_dir;          // where this scan's files go
  int64_t created_utime = 0;
  const AppConfig* config = nullptr;
};

// The daemon's counters at the time of a checkpoint.
struct FusionProgress {
  uint64_t frames_received = 0;
  uint64_t frames_fused = 0;
  uint64_t frames_dropped = 0;
  uint64_t frames_tracked_only = 0;  // fusion shed: the daemon was behind its camera
  uint64_t frames_lost = 0;          // tracking lost
};

// What a resumed scan continues with besides its map (CheckpointSink::restore).
struct RestoredScan {
  std::vector<StampedPose> trajectory;      // the poses recorded so far, corrected by loop closures
  std::vector<uint32_t> trajectory_frames;  // each one's frame id
  std::optional<ScanGraphState> graph;      // the pose graph of the checkpoint (FramePath::restore)
};

// A FrameStore of the scan's frame path (ScanSession runs FramePath over it): prepare_frame before
// each frame is processed (a pager loads the evicted chunks the frame will touch), frame_fused
// after each fused frame (poses, keyframes every fusion_daemon.keyframe_every_n_frames, paging of
// the map around the camera).
class CheckpointSink : public FrameStore {
 public:
  // "none", "sqlite:/var/lib/depthfuse/scans/x.dfscan", ... for heartbeats and logs.
  virtual std::string describe() const = 0;
  virtual Status begin_scan(const ScanContext& scan) = 0;
  // Right after begin_scan, with the scan's fresh reconstructor: a sink that found an existing
  // scan (a restart after a crash) puts its last checkpoint back (map, next frame id, last pose,
  // the map's deformation), may rename the scan to the stored one, and fills in the trajectory
  // recorded so far and the pose graph.
  virtual Status restore(IncrementalReconstructor& reconstructor, ScanContext* scan,
                         RestoredScan* restored) {
    (void)reconstructor;
    (void)scan;
    (void)restored;
    return Status::ok();
  }
  // The pose graph the next checkpoint (or end_scan) keeps with the map.
  virtual void keep_graph(GraphCheckpoint graph) { (void)graph; }
  // A loop closure was applied before frame `before_frame`: the poses stored of the frames before
  // it move with their keyframes.
  virtual void poses_corrected(const AppliedCorrection& correction, uint32_t before_frame) {
    (void)correction;
    (void)before_frame;
  }
  Status prepare_frame(const Frame& frame, const Pose& T_world_cam_initial,
                       IncrementalReconstructor& reconstructor) override {
    (void)frame;
    (void)T_world_cam_initial;
    (void)reconstructor;
    return Status::ok();
  }
  // reason: "periodic" (every fusion_daemon.checkpoint_interval_s, only when durable()) or
  // "command" (depthfuse scan checkpoint). A periodic checkpoint may be written in the background
  // (the frames keep coming); a commanded one is written when this returns.
  virtual Status checkpoint(const std::string& reason, IncrementalReconstructor& reconstructor,
                            const FusionProgress& progress) = 0;
  // A background checkpoint is still being written: the next periodic one waits for it.
  virtual bool checkpoint_in_flight() const { return false; }
  // How long the last background checkpoint took from its snapshot to its commit, s: the daemon
  // starts the next one that much before the interval is up, so that what a crash can lose stays
  // within fusion_daemon.checkpoint_interval_s.
  virtual double checkpoint_latency_s() const { return 0.0; }
  // The scan is over; reconstructor.finish() has post-filtered the resident map. reason: "final"
  // (stop, new scan) or "sigterm". A durable sink writes its final checkpoint here.
  virtual Status end_scan(const std::string& reason, IncrementalReconstructor& reconstructor,
                          const FusionProgress& progress) = 0;
  // Writes the scan's whole cloud as binary PLY to `ply_path` and says how many points. A sink that
  // evicted chunks from memory writes them too (e.g. streamed from its file).
  virtual Result<size_t> write_cloud(const std::string& ply_path,
                                     IncrementalReconstructor& reconstructor) {
    const PointArrays cloud = reconstructor.map().gather();
    DF_RETURN_IF_ERROR(write_ply(ply_path, cloud, PlyOptions{}));
    return cloud.size();
  }
  // Figures for the heartbeat's counters (name, value).
  virtual void add_counters(std::vector<std::pair<std::string, double>>* counters) const {
    (void)counters;
  }
  // The latest failure that add_counters() counts and no call has returned yet (those of the
  // sink's own threads: a background checkpoint, a log), ok when there is none. The daemon takes it
  // with the counters, so that a heartbeat never counts a failure without showing its error.
  virtual Status take_unreported_failure() { return Status::ok(); }
  // True when checkpoint() actually stores something (false: the periodic timer is not run).
  virtual bool durable() const = 0;
};

class NullCheckpointSink : public CheckpointSink {
 public:
  std::string describe() const override { return "none"; }
  Status begin_scan(const ScanContext&) override { return Status::ok(); }
  Status frame_fused(const Frame&, const FrameReport&, IncrementalReconstructor&) override {
    return Status::ok();
  }
  Status checkpoint(const std::string&, IncrementalReconstructor&, const FusionProgress&) override {
    return Status::ok();
  }
  Status end_scan(const std::string&, IncrementalReconstructor&, const FusionProgress&) override {
    return Status::ok();
  }
  bool durable() const override { return false; }
};

// The sink this build has: the SQLite scan store when it is built in, else NullCheckpointSink.
// `scan_db_path` (--scan-db): the first scan's file; empty: a file per scan in the scan directory.
std::unique_ptr<CheckpointSink> make_checkpoint_sink(const AppConfig& config,
                                                     const std::string& scan_db_path = "");

}  // namespace depthfuse::fusiond
