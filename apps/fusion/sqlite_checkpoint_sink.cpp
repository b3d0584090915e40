// The SQLite checkpoint sink (see sqlite_checkpoint_sink.hpp). Owned by the fusion daemon and
// called from its worker thread, but for describe() once at start-up; the heartbeat reads a copy
// of its counters.
#include "sqlite_checkpoint_sink.hpp"

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "depthfuse/base/log.hpp"
#include "depthfuse/store/export.hpp"
#include "memory_budget.hpp"

DF_LOG_CATEGORY(Fusion)

namespace depthfuse::fusiond {

namespace {

// The configuration text stored with the scan: the file the daemon was started with, if any.
std::string config_text(const AppConfig& config) {
  if (config.source_path.empty()) return "";
  std::ifstream in(config.source_path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

}  // namespace

SqliteCheckpointSink::SqliteCheckpointSink(const AppConfig& config, const SqliteSinkOptions& options)
    : config_(config), options_(options) {}

SqliteCheckpointSink::~SqliteCheckpointSink() = default;

// The daemon counts from its start; a resumed scan adds what the file counted before.
store::FrameCounters SqliteCheckpointSink::counters_of(const FusionProgress& p) const {
  return {resumed_.received + p.frames_received, resumed_.dropped + p.frames_dropped,
          resumed_.tracked_only + p.frames_tracked_only, resumed_.lost + p.frames_lost};
}

std::string SqliteCheckpointSink::describe() const {
  if (!path_.empty()) return "sqlite:" + path_;
  if (!options_.scan_db_path.empty() && !scan_db_used_) return "sqlite:" + options_.scan_db_path;
  return "sqlite:" + config_.fusion.scan_dir;
}

store::RecorderConfig SqliteCheckpointSink::recorder_config() const {
  store::RecorderConfig rc;
  rc.bounded_memory = true;
  rc.pager.memory_budget_mib = MemoryBudget::of(config_).map_mib();
  rc.pager.evict_distance_m = config_.fusion.evict_distance_m;
  rc.pager.min_age_frames = config_.fusion.evict_min_age_frames;
  rc.keyframe_every_n_frames = config_.fusion.keyframe_every_n_frames;
  rc.frame_log_interval_s = config_.fusion.frame_log_interval_s;
  return rc;
}

Status SqliteCheckpointSink::begin_scan(const ScanContext& scan) {
  recorder_.reset();  // a previous scan's file (and its write lock) is released
  resume_.reset();
  final_written_ = false;
  resumed_ = {};
  reported_failures_ = reported_log_failures_ = 0;
  if (!options_.scan_db_path.empty() && !scan_db_used_) {
    path_ = options_.scan_db_path;
    scan_db_used_ = true;
  } else {
    path_ = (std::filesystem::path(scan.scan_dir) / (scan.scan_id + ".dfscan")).string();
  }
  const store::RecorderConfig rc = recorder_config();
  std::error_code ec;
  if (std::filesystem::exists(path_, ec)) {
    auto at = std::make_unique<store::ResumePoint>();
    auto resumed = store::ScanRecorder::resume(path_, rc, at.get());
    if (!resumed) return resumed.status().with_context("resuming scan file " + path_);
    recorder_ = std::move(resumed).value();
    resume_ = std::move(at);
    return Status::ok();
  }
  store::ScanMetadata meta;
  meta.scan_id = scan.scan_id;
  meta.created_utime = scan.created_utime;
  meta.method = to_string(config_.reconstruction.pipeline.method);
  meta.chunk_size_m = config_.reconstruction.fusion.chunk_size_m;
  meta.software_version = "depthfuse-fusion";
  auto created = store::ScanRecorder::create(path_, meta, config_text(config_),
                                             config_.source_path, rc);
  if (!created) return created.status().with_context("creating scan file " + path_);
  recorder_ = std::move(created).value();
  return Status::ok();
}

Status SqliteCheckpointSink::restore(IncrementalReconstructor& reconstructor, ScanContext* scan,
                                     RestoredScan* restored) {
  if (store::MapPager* pager = recorder_ ? recorder_->pager() : nullptr)
    store::link_pager(pager, &reconstructor.deformation());
  if (recorder_)
    recorder_->set_pending_points(
        [&reconstructor] { return reconstructor.deformation().pending(); });
  if (!resume_) return Status::ok();
  std::unique_ptr<store::ResumePoint> at = std::move(resume_);
  if (!at->metadata.scan_id.empty()) scan->scan_id = at->metadata.scan_id;
  if (at->metadata.created_utime != 0) scan->created_utime = at->metadata.created_utime;
  resumed_ = store::frame_counters_of(at->metadata);
  std::unique_ptr<PointMap> map = std::move(at->map);
  if (!map) map = std::make_unique<PointMap>(config_.reconstruction.fusion.chunk_size_m);
  reconstructor.reset(std::move(map), at->next_frame_id, at->last_T_world_cam);
  // Before the log's frames are replayed: they are fused in the graph's version, and the stale
  // chunks they load follow the corrections made before the crash.
  DF_RETURN_IF_ERROR(store::restore_deformation(at->graph, std::move(at->pending), path_,
                                                &reconstructor.deformation(),
                                                &reconstructor.map())
                         .with_context("not resumed (`depthfuse inspect` lists what is wrong)"));
  if (at->graph) restored->graph = std::move(at->graph->graph);
  keep_history_for_evicted(reconstructor);
  restore_keyframes(reconstructor);
  restored->trajectory.clear();
  restored->trajectory_frames.clear();
  auto poses = recorder_->store().read_poses();
  if (!poses) return poses.status().with_context("reading the poses of " + path_);
  for (const auto& p : *poses) {
    restored->trajectory.push_back({p.utime * 1e-6, p.T_world_cam});
    restored->trajectory_frames.push_back(p.frame_id);
  }
  // The frames after the checkpoint that the redo log holds are fused again at their poses.
  auto replayed = recorder_->replay_log(reconstructor);
  if (!replayed) return replayed.status();
  // The replayed frames' poses, before the checkpoint below takes them.
  for (const auto& p : recorder_->pending_poses()) {
    restored->trajectory.push_back({p.utime * 1e-6, p.T_world_cam});
    restored->trajectory_frames.push_back(p.frame_id);
  }
  // A checkpoint of the replayed frames, at once and in the background: otherwise every restart
  // before the next full checkpoint would replay them again, and more.
  if (*replayed > 0)
    (void)recorder_->checkpoint_in_background(&reconstructor.map(), "replayed",
                                              resumed_);
  const auto& r = at->open_report;
  DF_LOG(Fusion, Info)
      << "resumed scan " << scan->scan_id << " from " << path_ << " at checkpoint "
      << (at->checkpoint ? at->checkpoint->id : 0) << " (frame " << at->next_frame_id - 1
      << "), replayed " << *replayed << " logged frames: next frame "
      << reconstructor.next_frame_id() << ", " << reconstructor.map().point_count()
      << " resident points; discarded after the checkpoint: " << r.discarded_poses << " poses, "
      << r.discarded_keyframes << " keyframes, " << r.discarded_staged_chunks << " staged chunks"
      << (restored->graph ? "; pose graph of " + std::to_string(restored->graph->keyframes.size()) +
                                " keyframes, " + std::to_string(restored->graph->loops.size()) +
                                " loops, version " + std::to_string(restored->graph->version)
                          : std::string());
  return Status::ok();
}

void SqliteCheckpointSink::keep_history_for_evicted(IncrementalReconstructor& reconstructor) {
  const store::MapPager* pager = recorder_ ? recorder_->pager() : nullptr;
  reconstructor.deformation().set_oldest_stored_version(pager ? pager->oldest_evicted_version()
                                                              : std::nullopt);
}

Status SqliteCheckpointSink::bring_stored_chunks_up_to_date(IncrementalReconstructor& reconstructor) {
  // Export would move a stale stored chunk's points where their keyframes went but could not merge
  // the surfaces that then lie on each other (a wall of the first lap and its drifted second),
  // which the sweep does for resident chunks: these are brought up to date as the sweep would,
  // a batch at a time so that the map stays within its budget and a batch. Bringing one up to
  // date may send points on into others that are out of date, taken in the next round (a chunk is
  // updated once per correction, so this ends).
  store::MapPager* pager = recorder_->pager();
  if (!pager) return Status::ok();  // nothing was ever evicted
  constexpr size_t kChunksPerBatch = 32;
  MapDeformation& deformation = reconstructor.deformation();
  PointMap& map = reconstructor.map();
  const uint64_t merged_before = deformation.stats().points_merged;
  const auto t0 = std::chrono::steady_clock::now();
  Status first_error;
  std::vector<ChunkKey> keys, before, batch, out_of_memory;
  size_t rounds = 0, chunks = 0, points = 0;
  for (;;) {
    keys = pager->evicted_before(deformation.version());
    const std::vector<ChunkKey> pending = deformation.pending_keys();
    keys.insert(keys.end(), pending.begin(), pending.end());
    std::sort(keys.begin(), keys.end());
    keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
    // What could not be loaded stays listed: stop once a round changes nothing.
    if (keys.empty() || keys == before) break;
    for (size_t i = 0; i < keys.size(); i += kChunksPerBatch) {
      batch.assign(keys.begin() + static_cast<std::ptrdiff_t>(i),
                   keys.begin() + static_cast<std::ptrdiff_t>(std::min(keys.size(), i + kChunksPerBatch)));
      // Only what was out of memory goes back out (after finish() no resident chunk is listed).
      out_of_memory.clear();
      for (const ChunkKey& k : batch)
        if (!map.find(k)) out_of_memory.push_back(k);
      Status st = pager->load_chunks(&map, batch, reconstructor.next_frame_id());
      if (!st && first_error) first_error = st;
      points += deformation.update(&map, batch);
      st = pager->evict_chunks(&map, out_of_memory);
      if (!st && first_error) first_error = st;
    }
    ++rounds;
    chunks += keys.size();
    before.swap(keys);
  }
  if (rounds > 0)
    DF_LOG(Fusion, Info) << "end of scan: " << chunks << " stored chunks brought up to date in "
                         << rounds << " rounds (" << points << " points, "
                         << deformation.stats().points_merged - merged_before << " merged), "
                         << std::chrono::duration<double, std::milli>(
                                std::chrono::steady_clock::now() - t0).count()
                         << " ms";
  keep_history_for_evicted(reconstructor);
  return first_error.with_context("bringing the stored chunks up to date");
}

void SqliteCheckpointSink::keep_graph(GraphCheckpoint graph) {
  if (recorder_) recorder_->set_graph(std::move(graph));
}

void SqliteCheckpointSink::poses_corrected(const AppliedCorrection& correction,
                                           uint32_t before_frame) {
  if (recorder_) recorder_->poses_corrected(correction, before_frame);
}

// A resumed scan without relocalisation keyframes could not find a camera that moved while it was
// down; one without some of them finds it in fewer places. Neither stops the scan: what went wrong
// is logged and fusion goes on.
void SqliteCheckpointSink::restore_keyframes(IncrementalReconstructor& reconstructor) {
  auto restored = recorder_->restore_keyframes(reconstructor);
  if (!restored) {
    DF_LOG(Fusion, Warning) << "resumed scan without relocalisation keyframes: "
                            << restored.status().to_string();
    return;
  }
  for (const std::string& why : restored->skipped)
    DF_LOG(Fusion, Warning) << "relocalisation keyframe skipped: " << why;
  DF_LOG(Fusion, Info) << "restored " << restored->restored << " relocalisation keyframes from "
                       << restored->stored << " stored (" << restored->chosen
                       << " chosen by place and decoded, " << restored->skipped.size()
                       << " skipped as damaged, " << restored->chunks_loaded
                       << " map chunks loaded for their views) in "
                       << static_cast<int>(restored->seconds * 1e3 + 0.5) << " ms";
}

Status SqliteCheckpointSink::prepare_frame(const Frame& frame, const Pose& T_world_cam_initial,
                                           IncrementalReconstructor& reconstructor) {
  if (!recorder_) return invalid_argument("no scan file is open");
  Status st = recorder_->prepare_frame(frame, T_world_cam_initial, reconstructor);
  keep_history_for_evicted(reconstructor);
  return st;
}

Status SqliteCheckpointSink::frame_fused(const Frame& frame, const FrameReport& report,
                                         IncrementalReconstructor& reconstructor) {
  if (!recorder_) return invalid_argument("no scan file is open");
  Status st = recorder_->record_frame(frame, report, &reconstructor.map());
  keep_history_for_evicted(reconstructor);
  return st;
}

Status SqliteCheckpointSink::frame_not_fused(const FrameReport& report,
                                             const Pose& T_world_cam_initial,
                                             IncrementalReconstructor& reconstructor) {
  if (!recorder_) return invalid_argument("no scan file is open");
  Status st = recorder_->keep_within_budget(&reconstructor.map(),
                                            T_world_cam_initial.translation().cast<float>(),
                                            reconstructor.next_frame_id(), report.graph_memory_bytes);
  keep_history_for_evicted(reconstructor);
  return st;
}

Status SqliteCheckpointSink::checkpoint(const std::string& reason, IncrementalReconstructor& reconstructor,
                                        const FusionProgress& progress) {
  if (!recorder_) return invalid_argument("no scan file is open");
  // Points waiting for their chunks to follow a correction are stored as they are (the recorder's
  // pending source): their chunks are not brought up to date here.
  // Periodic checkpoints come every second or so: written on the recorder's own thread from a snapshot
  // of what changed (the chunks' points shared, not copied), so that fusion does not wait for the encoding and the fsync. Their failures
  // are counted when the next recorder call collects the outcome, whichever call that is (a frame's
  // most often), and reach the heartbeat through take_unreported_failure.
  if (reason == "periodic") {
    (void)recorder_->checkpoint_in_background(&reconstructor.map(), reason, counters_of(progress));
    return Status::ok();
  }
  auto r = recorder_->checkpoint(&reconstructor.map(), reason, counters_of(progress));
  if (!r) {
    // Returned to the daemon: the newest counted failure is this one.
    reported_failures_ = recorder_->status().checkpoint_failures;
    return r.status().with_context("checkpoint of " + path_ + " (the last good one is kept)");
  }
  return Status::ok();
}

Status SqliteCheckpointSink::take_unreported_failure() {
  if (!recorder_) return Status::ok();
  const store::RecorderStatus& s = recorder_->status();
  std::vector<Status> failures;
  if (s.checkpoint_failures > reported_failures_) {
    reported_failures_ = s.checkpoint_failures;
    failures.push_back(s.last_checkpoint_failure);
  }
  if (s.frame_log.failures > reported_log_failures_) {
    reported_log_failures_ = s.frame_log.failures;
    failures.push_back(s.frame_log.last_error.with_context(
        "frame log (a crash before the next checkpoint loses the frames it could not log)"));
  }
  if (failures.empty()) return Status::ok();
  // Both at once when the disk is full: the checkpoint's is the graver, and both are kept.
  Status failure = failures.front();
  for (size_t i = 1; i < failures.size(); ++i)
    failure = Status(failure.code(), failure.message() + "; " + failures[i].to_string());
  return failure;
}

bool SqliteCheckpointSink::checkpoint_in_flight() const {
  return recorder_ && recorder_->checkpoint_in_flight();
}

double SqliteCheckpointSink::checkpoint_latency_s() const {
  return recorder_ ? recorder_->status().last_checkpoint_seconds : 0.0;
}

Status SqliteCheckpointSink::end_scan(const std::string& reason, IncrementalReconstructor& reconstructor,
                                      const FusionProgress& progress) {
  if (!recorder_) return invalid_argument("no scan file is open");
  if (Status st = bring_stored_chunks_up_to_date(reconstructor); !st)
    DF_LOG(Fusion, Warning) << st.to_string();
  auto r = recorder_->finish(&reconstructor.map(), counters_of(progress), reason);
  if (!r) {
    reported_failures_ = recorder_->status().checkpoint_failures;  // returned to the daemon
    return r.status().with_context("final checkpoint of " + path_);
  }
  final_written_ = true;
  return Status::ok();
}

Result<size_t> SqliteCheckpointSink::write_cloud(const std::string& ply_path,
                                                 IncrementalReconstructor& reconstructor) {
  if (!recorder_) return CheckpointSink::write_cloud(ply_path, reconstructor);
  if (!final_written_) {
    // The file lacks the end of the scan. With nothing evicted the resident map is the whole
    // cloud; otherwise it would lack the evicted chunks: refuse, so that the daemon keeps the scan
    // (paused) and the operator can stop it again.
    const store::MapPager* pager = recorder_->pager();
    if (!pager || (pager->evicted().empty() && pager->stats().total_evicted == 0))
      return CheckpointSink::write_cloud(ply_path, reconstructor);
    return io_error("the final checkpoint of " + path_ +
                    " was not written, so the scan's cloud cannot be exported from it");
  }
  // export_cloud picks the format by the name's suffix; ply_path may be a temporary name.
  const bool is_ply = ply_path.size() >= 4 && ply_path.compare(ply_path.size() - 4, 4, ".ply") == 0;
  const std::string out = is_ply ? ply_path : ply_path + ".ply";
  auto exported = store::export_cloud(recorder_->store(), out);
  if (!exported) return exported.status().with_context("exporting " + path_);
  if (!is_ply) {
    std::error_code ec;
    std::filesystem::rename(out, ply_path, ec);
    if (ec) {
      std::filesystem::remove(out, ec);
      return io_error("cannot rename " + out + " to " + ply_path + ": " + ec.message());
    }
  }
  recorder_.reset();  // the scan is over: release the file
  return static_cast<size_t>(exported->points_written);
}

void SqliteCheckpointSink::add_counters(std::vector<std::pair<std::string, double>>* counters) const {
  if (!recorder_) return;
  const store::RecorderStatus& s = recorder_->status();
  counters->emplace_back("checkpoints_written", static_cast<double>(s.checkpoints_written));
  counters->emplace_back("checkpoint_failures", static_cast<double>(s.checkpoint_failures));
  counters->emplace_back("last_checkpoint_frame",
                         s.last_checkpoint ? static_cast<double>(s.last_checkpoint->last_frame_id) : 0.0);
  // The last background checkpoint: the fusion thread's share (copying the changed chunks), then
  // the writer thread's (encoding them; the transaction with its fsync).
  counters->emplace_back("checkpoint_snapshot_ms", s.last_snapshot_seconds * 1e3);
  counters->emplace_back("checkpoint_encode_ms", s.last_encode_seconds * 1e3);
  counters->emplace_back("checkpoint_write_ms", s.last_write_seconds * 1e3);
  counters->emplace_back("checkpoint_chunks", static_cast<double>(s.last_checkpoint_chunks));
  // The frame redo log's thread: frames committed, the newest, those waiting, and its CPU time so
  // far (encoding; the transactions), whose growth per second is durability's cost.
  counters->emplace_back("frame_log_frames", static_cast<double>(s.frame_log.frames_logged));
  counters->emplace_back("frame_log_last_frame", static_cast<double>(s.frame_log.last_logged_frame));
  counters->emplace_back("frame_log_waiting", static_cast<double>(s.frame_log.frames_waiting));
  counters->emplace_back("frame_log_failures", static_cast<double>(s.frame_log.failures));
  // Frames not logged: after failures beyond its memory bound the log stops until a checkpoint
  // holds every frame it dropped (a crash before then loses them).
  counters->emplace_back("frame_log_dropped", static_cast<double>(s.frame_log.frames_dropped));
  // And frames fused after a loop closure before the checkpoint that holds it (a crash then loses
  // them: the log cannot replay them over the map of before the correction).
  counters->emplace_back("frame_log_skipped_after_correction",
                         static_cast<double>(s.frames_not_logged_after_correction));
  counters->emplace_back("frame_log_encode_s", s.frame_log.encode_seconds);
  counters->emplace_back("frame_log_write_s", s.frame_log.write_seconds);
  counters->emplace_back("frame_log_cpu_s", s.frame_log.cpu_seconds);
  // How far behind the log is (the oldest frame not committed, now; the most a committed frame
  // waited), and what keeping it within frame_log_interval_s cost fusion: the time the worker
  // waited for it, and how often it waited because the log was that far behind.
  counters->emplace_back("frame_log_lag_ms", s.frame_log.lag_seconds * 1e3);
  counters->emplace_back("frame_log_max_lag_ms", s.frame_log.max_lag_seconds * 1e3);
  counters->emplace_back("frame_log_wait_s", s.frame_log.waited_seconds);
  counters->emplace_back("frame_log_lag_waits", static_cast<double>(s.frame_log.lag_waits));
  // The checkpoint writer's thread time so far, comparable with the log's.
  counters->emplace_back("checkpoint_encode_s", s.total_encode_seconds);
  counters->emplace_back("checkpoint_write_s", s.total_write_seconds);
  counters->emplace_back("resident_mib", s.pager.resident_bytes / (1024.0 * 1024.0));
  counters->emplace_back("evicted_chunks", static_cast<double>(s.pager.evicted_chunks));
  // Paging activity since the scan (or its resume) began: chunks written out and brought back.
  counters->emplace_back("chunks_evicted_total", static_cast<double>(s.pager.total_evicted));
  counters->emplace_back("chunks_loaded_total", static_cast<double>(s.pager.total_loaded));
  // Chunks loaded back where the map had made a new one meanwhile (the two are joined).
  counters->emplace_back("chunk_load_collisions", static_cast<double>(s.pager.load_collisions));
}

}  // namespace depthfuse::fusiond
