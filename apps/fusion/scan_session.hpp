// One scan of the fusion daemon, without LCM and without threads of its own: its life (start, or
// resume from its file; stop and save), the per-frame path (FramePath over the checkpoint sink)
// and the periodic checkpoint. FusionDaemon drives it from its worker thread; a test or a tool
// can drive it the same way with frames of its own.
#pragma once

#include <chrono>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "checkpoint_sink.hpp"
#include "depthfuse/app_config.hpp"
#include "depthfuse/frame_path.hpp"
#include "depthfuse/incremental.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::fusiond {

class ScanSession {
 public:
  // `sink` outlives the session.
  ScanSession(const AppConfig& config, CheckpointSink& sink);
  ~ScanSession();

  // Whether a scan may start now: not sooner than fusion_daemon.min_scan_interval_s after the last
  // one started, and with fusion_daemon.min_free_disk_mib free in the scan directory.
  Status may_start() const;
  // A new scan, or the scan file's (a restart after a crash) continued from its last checkpoint.
  // `requested_name` empty or "-": a name from the time. Says which ("scan X started", "scan X
  // resumed at frame N").
  Result<std::string> start(const std::string& requested_name);
  // The frame's whole path: predict, prepare the map, process, record (frame_path.hpp). A fused
  // frame's pose joins the trajectory; one tracked only (FrameWork::kTrackOnly) does not.
  Result<FrameOutcome> process(const Frame& frame, FrameWork work = FrameWork::kTrackAndFuse);
  // A periodic checkpoint is due: checkpoint_interval_s since the last, less the time the last one
  // took to commit (so that what a crash can lose stays within the interval), and none in flight.
  bool checkpoint_due() const;
  // reason "periodic" (may be written in the background) or "command" (written when this returns).
  Status checkpoint(const std::string& reason, const FusionProgress& progress);
  struct Saved {
    std::string message;  // what was saved where
    Status store;         // the final checkpoint's failure: the cloud and trajectory were saved
  };
  // Post-filters the map, writes the final checkpoint, the cloud (PLY) and the trajectory (TUM) to
  // the scan directory, each through a temporary file and a rename. On success the scan is over;
  // on failure the scan stays as it is, so that the caller can fix the cause and stop again.
  Result<Saved> stop(const std::string& reason, const FusionProgress& progress);
  // Where stop() saves the cloud and the trajectory (SIGTERM's last resort: a temporary directory).
  void save_to(const std::string& scan_dir) { scan_.scan_dir = scan_dir; }

  bool active() const { return reconstructor_ != nullptr; }
  const std::string& scan_id() const { return scan_.scan_id; }
  // Null between scans.
  const IncrementalReconstructor* reconstructor() const { return reconstructor_.get(); }
  const std::vector<StampedPose>& trajectory() const { return trajectory_; }
  // Each trajectory pose's frame sequence (0 where it is not known: fused before a resume).
  const std::vector<int64_t>& trajectory_sequences() const { return trajectory_sequences_; }
  // Null between scans.
  const FramePath* path() const { return path_.get(); }
  // The sequence of a frame this scan fused (0 when it is not known: fused before a resume).
  int64_t sequence_of(uint32_t frame_id) const;
  size_t point_count() const { return reconstructor_ ? reconstructor_->map().point_count() : 0; }

 private:
  // A loop closure applied before frame `before_frame`: the poses of the frames before it move
  // with their keyframes, here and in the sink's store.
  void correct_trajectory(const AppliedCorrection& correction, uint32_t before_frame);

  const AppConfig& config_;
  CheckpointSink& sink_;
  std::unique_ptr<IncrementalReconstructor> reconstructor_;
  std::unique_ptr<FramePath> path_;
  std::vector<StampedPose> trajectory_;
  std::vector<uint32_t> trajectory_frames_;  // each pose's frame id, to move it with a closure
  std::vector<int64_t> trajectory_sequences_;  // and its frame's sequence
  ScanContext scan_;
  std::chrono::steady_clock::time_point last_checkpoint_;
  std::optional<std::chrono::steady_clock::time_point> last_start_;  // min_scan_interval_s
};

}  // namespace depthfuse::fusiond
