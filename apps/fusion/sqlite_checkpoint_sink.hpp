// CheckpointSink on the SQLite scan store: one scan file per scan (store::ScanRecorder), bounded
// memory through its MapPager, a WAL transaction per checkpoint, and resume from the last
// checkpoint when the scan file already exists (a restart after a crash or kill -9).
#pragma once

#include <memory>
#include <string>

#include "checkpoint_sink.hpp"
#include "depthfuse/store/scan_recorder.hpp"

namespace depthfuse::fusiond {

struct SqliteSinkOptions {
  // The first scan of the process goes to this file (created, or resumed when it exists). Empty:
  // every scan gets `<fusion_daemon.scan_dir>/<scan id>.dfscan` (resumed when it exists).
  std::string scan_db_path;
};

class SqliteCheckpointSink : public CheckpointSink {
 public:
  SqliteCheckpointSink(const AppConfig& config, const SqliteSinkOptions& options);
  ~SqliteCheckpointSink() override;

  std::string describe() const override;
  Status begin_scan(const ScanContext& scan) override;
  Status restore(IncrementalReconstructor& reconstructor, ScanContext* scan,
                 RestoredScan* restored) override;
  void keep_graph(GraphCheckpoint graph) override;
  void poses_corrected(const AppliedCorrection& correction, uint32_t before_frame) override;
  Status prepare_frame(const Frame& frame, const Pose& T_world_cam_initial,
                       IncrementalReconstructor& reconstructor) override;
  Status frame_not_fused(const FrameReport& report, const Pose& T_world_cam_initial,
                         IncrementalReconstructor& reconstructor) override;
  Status frame_fused(const Frame& frame, const FrameReport& report,
                     IncrementalReconstructor& reconstructor) override;
  Status checkpoint(const std::string& reason, IncrementalReconstructor& reconstructor,
                    const FusionProgress& progress) override;
  bool checkpoint_in_flight() const override;
  double checkpoint_latency_s() const override;
  Status end_scan(const std::string& reason, IncrementalReconstructor& reconstructor,
                  const FusionProgress& progress) override;
  Result<size_t> write_cloud(const std::string& ply_path,
                             IncrementalReconstructor& reconstructor) override;
  void add_counters(std::vector<std::pair<std::string, double>>* counters) const override;
  Status take_unreported_failure() override;
  bool durable() const override { return true; }

  // The scan file of the current (or last) scan.
  const std::string& path() const { return path_; }

 private:
  store::RecorderConfig recorder_config() const;
  store::FrameCounters counters_of(const FusionProgress& progress) const;
  // restore(): the stored keyframes back into the relocaliser, logged; never fails the resume.
  void restore_keyframes(IncrementalReconstructor& reconstructor);
  // The map's deformation keeps the history the evicted chunks need (after every pager call).
  void keep_history_for_evicted(IncrementalReconstructor& reconstructor);
  // The end of a scan, after the resident map followed the last correction: the evicted chunks
  // stored in an older version, and those that points moved into wait for, follow it too, loaded
  // a batch at a time and put back. A chunk that cannot be loaded (damaged) stays as stored.
  Status bring_stored_chunks_up_to_date(IncrementalReconstructor& reconstructor);

  AppConfig config_;
  SqliteSinkOptions options_;
  bool scan_db_used_ = false;       // --scan-db is for the first scan only
  std::string path_;
  std::unique_ptr<store::ScanRecorder> recorder_;
  std::unique_ptr<store::ResumePoint> resume_;  // between begin_scan and restore
  bool final_written_ = false;      // end_scan's checkpoint committed
  store::FrameCounters resumed_;  // counted before a resume
  // Failures counted in the recorder's status that the daemon has had (returned by a call, or by
  // take_unreported_failure).
  uint64_t reported_failures_ = 0;      // checkpoints
  uint64_t reported_log_failures_ = 0;  // frame log commits and encodings
};

}  // namespace depthfuse::fusiond
