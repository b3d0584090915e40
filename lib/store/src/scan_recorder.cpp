// The fusion daemon's use of the store: owns the scan file's writer, the pager and the poses since
// the last checkpoint. Runs on the fusion daemon's worker thread (SqliteCheckpointSink), on that
// thread's connection; the background checkpoints and the frame log have threads and connections
// of their own.
#include "depthfuse/store/scan_recorder.hpp"

#include <malloc.h>

#include "checkpoint_writer.hpp"
#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/fusion.hpp"
#include "frame_log_writer.hpp"

DF_LOG_CATEGORY(Store)

namespace depthfuse::store {

ScanRecorder::ScanRecorder(std::unique_ptr<ScanStore> store, const RecorderConfig& config)
    : store_(std::move(store)), config_(config) {
  status_.path = store_->path();
  if (config_.bounded_memory) {
    pager_ = std::make_unique<MapPager>(config_.pager, store_.get());
    pager_->set_checkpoint_hooks([this] { return writer_ && writer_->writing(); },
                                 [this] {
                                   if (writer_) writer_->wait_idle();
                                 });
  }
}

Status ScanRecorder::start_frame_log() {
  if (config_.frame_log_interval_s <= 0) return Status::ok();
  FrameLogWriterConfig lc;
  // A tenth of the interval is left for the frame on its way from fusion to the log (its pose is
  // published first) and for the moment of a crash: what one loses stays within the interval.
  lc.max_lag_s = 0.9 * config_.frame_log_interval_s;
  lc.queue_frames = std::max<size_t>(1, config_.frame_log_queue_frames);
  lc.commit_bytes = config_.frame_log_commit_bytes;
  lc.compression_level = config_.frame_log_compression_level;
  lc.color_compression_level = config_.frame_log_color_compression_level;
  lc.locked_timeout_s = config_.store.busy_timeout_ms * 1e-3;
  // The thread retries a locked file itself, encoding on meanwhile: no busy wait inside SQLite.
  StoreOptions options = config_.store;
  options.busy_timeout_ms = 0;
  auto connection = store_->another_connection(options);
  if (!connection) return connection.status().with_context("opening the frame log's connection");
  frame_log_ = std::make_unique<FrameLogWriter>(std::move(connection).value(), lc);
  return Status::ok();
}

size_t RecorderConfig::frame_log_bytes(const RecorderConfig& config, size_t pixels) {
  if (config.frame_log_interval_s <= 0) return 0;
  const size_t raw_frame = pixels * (sizeof(float) + 3), encoded_frame = pixels * (2 + 3);
  return (std::max<size_t>(1, config.frame_log_queue_frames) + 1) * raw_frame +
         2 * (config.frame_log_commit_bytes + encoded_frame);
}

namespace {
// Keyframes the fusion thread holds while the background writer has the store (~1 MB each).
constexpr size_t kMaxPendingKeyframes = 4;
}  // namespace

Status ScanRecorder::write_pending_keyframes() {
  Status result;
  for (const Keyframe& k : pending_keyframes_) {
    Status st = store_->write_keyframe(k);
    if (st) ++status_.keyframes_written;
    else if (result) result = note(st);
  }
  pending_keyframes_.clear();
  return result;
}

// The fusion thread does not wait for another thread's transaction when it need not: keyframes
// wait for a frame where the file is free (SQLite's write lock would hold the fusion thread for
// the rest of that transaction), until kMaxPendingKeyframes of them are waiting.
Status ScanRecorder::catch_up(PointMap* map) {
  collect_background(map);
  if (pending_keyframes_.empty()) return Status::ok();
  const bool file_busy = (writer_ && writer_->writing()) || (frame_log_ && frame_log_->writing());
  if (file_busy && pending_keyframes_.size() < kMaxPendingKeyframes) return Status::ok();
  return write_pending_keyframes();
}

ScanRecorder::~ScanRecorder() = default;

Status ScanRecorder::note(Status st) {
  if (!st) {
    status_.last_error_code = st.code();
    status_.last_error = st.to_string();
  }
  return st;
}

Result<std::unique_ptr<ScanRecorder>> ScanRecorder::create(const std::string& path,
                                                           const ScanMetadata& metadata,
                                                           const std::string& config_toml,
                                                           const std::string& config_source,
                                                           const RecorderConfig& config) {
  if (config.bounded_memory) DF_RETURN_IF_ERROR(MapPager::validate(config.pager));
  auto store = ScanStore::open(path, OpenMode::kCreate, config.store);
  if (!store) return store.status();
  ScanMetadata meta = metadata;
  if (meta.created_utime == 0) {
    meta.created_utime = now_utime();
  }
  DF_RETURN_IF_ERROR((*store)->set_metadata(meta));
  DF_RETURN_IF_ERROR((*store)->set_config(config_toml, config_source));
  std::unique_ptr<ScanRecorder> rec(new ScanRecorder(std::move(store).value(), config));
  DF_RETURN_IF_ERROR(rec->start_frame_log());
  return rec;
}

Status restore_deformation(const std::optional<GraphCheckpoint>& graph,
                           std::vector<PendingPoints> pending, const std::string& path,
                           MapDeformation* deformation, PointMap* map) {
  if (!graph) {
    if (pending.empty()) return Status::ok();
    return corrupt(path + ": " + std::to_string(pending.size()) +
                   " rows of points pending for a loop closure's correction, but no pose graph");
  }
  DF_RETURN_IF_ERROR(deformation->restore(graph->deformation)
                         .with_context("restoring the map's deformation from " + path));
  map->set_version(deformation->version());
  return deformation->restore_pending(std::move(pending))
      .with_context("restoring the points pending in " + path);
}

void link_pager(MapPager* pager, MapDeformation* deformation) {
  pager->set_bring_up_to_date(
      [deformation](PointMap* map, const ChunkKey& key) { deformation->update(map, {key}); });
  deformation->set_stored_elsewhere([pager](const ChunkKey& key) { return pager->is_evicted(key); });
}

Result<std::unique_ptr<ScanRecorder>> ScanRecorder::resume(const std::string& path,
                                                           const RecorderConfig& config,
                                                           ResumePoint* resume) {
  if (config.bounded_memory) DF_RETURN_IF_ERROR(MapPager::validate(config.pager));
  auto opened = ScanStore::open(path, OpenMode::kReadWrite, config.store);
  if (!opened) return opened.status();
  std::unique_ptr<ScanRecorder> rec(new ScanRecorder(std::move(opened).value(), config));
  ScanStore& store = *rec->store_;
  auto meta = store.metadata();
  if (!meta) return meta.status();
  auto last = store.last_checkpoint();
  if (!last) return last.status();
  // The frame ids continue from the file's: numbers that disagree would give two frames one id or
  // a trajectory with holes, so the scan is not resumed.
  if (const std::vector<std::string> problems = store.frame_problems(); !problems.empty()) {
    std::string all;
    for (const std::string& p : problems) all += (all.empty() ? "" : "; ") + p;
    return corrupt(all + " (not resumed: `depthfuse inspect` lists what is wrong)");
  }
  resume->metadata = *meta;
  resume->checkpoint = *last;
  resume->open_report = store.open_report();
  resume->map = std::make_unique<PointMap>(meta->chunk_size_m);
  resume->next_frame_id = 1;
  resume->last_T_world_cam.reset();
  if (*last) {
    resume->next_frame_id = (*last)->last_frame_id + 1;
    resume->last_T_world_cam = (*last)->T_world_cam;
    rec->last_frame_id_ = (*last)->last_frame_id;
    rec->last_pose_ = (*last)->T_world_cam;
    rec->frames_fused_ = (*last)->frames_fused;
    rec->status_.last_checkpoint = *last;
  }
  rec->status_.frames_recorded = rec->frames_fused_;
  if (rec->pager_) {
    // Everything starts on disk; the pager brings back what is near the camera.
    auto keys = store.list_chunks();
    if (!keys) return keys.status();
    for (const ChunkInfo& c : *keys) rec->pager_->mark_evicted(c.key, c.version);
    // The surroundings of the last pose; prepare_frame() brings back whatever the next frames see.
    Eigen::Vector3f cam = Eigen::Vector3f::Zero();
    if (resume->last_T_world_cam) cam = resume->last_T_world_cam->translation().cast<float>();
    DF_RETURN_IF_ERROR(rec->pager_
                           ->load_around(resume->map.get(), cam, config.pager.evict_distance_m,
                                         resume->next_frame_id)
                           .with_context("resuming"));
  } else {
    PointMap* map = resume->map.get();
    DF_RETURN_IF_ERROR(store.for_each_chunk([&](const ChunkInfo& info, PointArrays& points) {
      Chunk c;
      c.points_for_write() = std::move(points);
      c.last_touched_frame = c.last_seen_frame = info.last_touched_frame;
      c.version = info.version;
      c.dirty = false;
      map->insert(info.key, std::move(c));
      return Status::ok();
    }));
  }
  if (rec->pager_) rec->status_.pager = rec->pager_->stats();
  auto graph = store.read_graph();
  if (!graph) return graph.status().with_context("resuming");
  resume->graph = std::move(*graph);
  auto pending = store.read_pending();
  if (!pending) return pending.status().with_context("resuming");
  resume->pending = std::move(*pending);
  auto log = store.frame_log_summary();
  if (!log) return log.status();
  resume->frame_log = *log;
  rec->replay_pending_ = log->count > 0;
  DF_RETURN_IF_ERROR(rec->start_frame_log());
  return rec;
}

Result<size_t> ScanRecorder::replay_log(IncrementalReconstructor& reconstructor) {
  if (!replay_pending_) return size_t{0};
  replay_pending_ = false;
  replaying_ = true;
  // Read a few records at a time and fuse them with the read statement finished: fusing pages
  // chunks in and out of the same file.
  constexpr size_t kBatch = 4;
  size_t replayed = 0;
  uint32_t after = 0;
  Status damaged;
  std::vector<LoggedFrame> batch;
  for (;;) {
    batch.clear();
    Status st = store_->for_each_logged_frame(
        [&](LoggedFrame& f) {
          batch.push_back(std::move(f));
          return Status::ok();
        },
        after, kBatch);
    if (!st && st.code() != StatusCode::kCorrupt) {
      // Not a damaged record but a file that cannot be read now: nothing is dropped.
      replaying_ = false;
      return note(st.with_context("reading the frame log of " + store_->path()));
    }
    if (!st) damaged = st;
    for (LoggedFrame& f : batch) {
      // The stored pose is where the pager looks for the chunks the frame will touch.
      f.frame.T_world_cam_hint = f.pose.T_world_cam;
      Status done = prepare_frame(f.frame, f.pose.T_world_cam, reconstructor);
      if (done) done = reconstructor.replay(f.frame, f.pose.frame_id, f.pose.T_world_cam);
      if (done) {
        FrameReport report;
        report.frame_id = f.pose.frame_id;
        report.T_world_cam = f.pose.T_world_cam;
        report.registered = f.pose.registered;
        report.registration.fitness = f.pose.fitness;
        report.registration.rmse_m = f.pose.rmse_m;
        report.registration.correspondences = f.pose.correspondences;
        done = record_frame(f.frame, report, &reconstructor.map());
      }
      if (!done) {
        replaying_ = false;
        return note(done.with_context("replaying the frame log of " + store_->path() + " at frame " +
                                      std::to_string(f.pose.frame_id)));
      }
      after = f.pose.frame_id;
      ++replayed;
    }
    if (!damaged.is_ok() || batch.size() < kBatch) break;
  }
  replaying_ = false;
  if (!damaged) {
    // The damaged record and those after it cannot be replayed; the next frames take their ids.
    DF_LOG(Store, Warning) << damaged.message() << ": the frame log is replayed up to frame " << after
                           << " (" << replayed << " frames); the records after it are dropped";
    DF_RETURN_IF_ERROR(note(store_->discard_frame_log_from(after + 1)));
  }
  return replayed;
}

Status ScanRecorder::flush_frame_log() {
  if (!frame_log_) return Status::ok();
  const Status st = frame_log_->flush();
  status_.frame_log = frame_log_->stats();
  return st;
}

Status ScanRecorder::prepare_frame(const Frame& frame, const Pose& T_world_cam_initial,
                                   IncrementalReconstructor& reconstructor) {
  if (!pager_) return Status::ok();
  (void)catch_up(&reconstructor.map());
  Status st = pager_->prepare(&reconstructor.map(), frame, T_world_cam_initial,
                              reconstructor.next_frame_id());
  status_.pager = pager_->stats();
  return note(st);
}

Status ScanRecorder::keep_within_budget(PointMap* map, const Eigen::Vector3f& camera_m,
                                        uint32_t frame_id, size_t other_bytes) {
  if (!pager_) return Status::ok();
  pager_->set_other_bytes(other_bytes);
  Status st = pager_->update(map, camera_m, frame_id);
  status_.pager = pager_->stats();
  return note(st);
}

Status ScanRecorder::record_frame(const Frame& frame, const FrameReport& report, PointMap* map) {
  if (replay_pending_)
    return note(invalid_argument(store_->path() + ": the frame log's records are not replayed yet "
                                 "(ScanRecorder::replay_log after resume)"));
  PoseRecord p;
  p.frame_id = report.frame_id;
  p.utime = frame.utime;
  p.T_world_cam = report.T_world_cam;
  p.registered = report.registered;
  p.fitness = report.registration.fitness;
  p.rmse_m = report.registration.rmse_m;
  p.correspondences = static_cast<uint32_t>(report.registration.correspondences);
  pending_poses_.push_back(p);
  // A copy to the log's thread, which encodes and commits it (replayed frames are logged already).
  // Not a frame fused after a correction that no checkpoint has taken yet: the log holds poses, not
  // corrections, and replayed over the map of before the correction the frame would land where
  // that map was. A crash before the checkpoint loses it instead.
  if (frame_log_ && !replaying_) {
    if (!corrections_.empty()) {
      ++status_.frames_not_logged_after_correction;
    } else {
      frame_log_->push(p, frame);
      status_.frame_log = frame_log_->stats();
    }
  }
  last_frame_id_ = report.frame_id;
  last_pose_ = report.T_world_cam;
  ++frames_fused_;
  ++status_.frames_recorded;
  status_.pending_poses = pending_poses_.size();

  const int every = config_.keyframe_every_n_frames;
  if (every > 0 && (frames_since_keyframe_ % static_cast<uint64_t>(every)) == 0 &&
      !frame.depth.empty())
    pending_keyframes_.push_back(
        Keyframe::from_frame(frame, report.frame_id, report.T_world_cam, config_.keyframe_color));
  ++frames_since_keyframe_;
  Status result = catch_up(map);

  if (pager_) {
    pager_->set_other_bytes(report.graph_memory_bytes);
    Status st = pager_->update(map, report.T_world_cam.translation().cast<float>(), report.frame_id);
    status_.pager = pager_->stats();
    if (!st && result) result = note(st);
  }
  if (result) {
    status_.last_error_code = StatusCode::kOk;
    status_.last_error.clear();
  }
  return result;
}

void ScanRecorder::poses_corrected(const AppliedCorrection& correction, uint32_t before_frame) {
  corrections_.push_back({correction, before_frame});
  if (last_pose_) last_pose_ = correction.motion_of(last_frame_id_) * *last_pose_;
}

Result<CheckpointRecord> ScanRecorder::checkpoint(PointMap* map, const std::string& reason,
                                                  const FrameCounters& counters) {
  return write_checkpoint(map, reason, counters, false);
}

Result<CheckpointRecord> ScanRecorder::finish(PointMap* map, const FrameCounters& counters,
                                              const std::string& reason) {
  auto rec = write_checkpoint(map, reason, counters, true);
  // Pages freed by rewritten and promoted chunks go back to the file system; failing here loses
  // nothing (the checkpoint is committed).
  if (rec) (void)note(store_->compact());
  return rec;
}

CheckpointInfo ScanRecorder::checkpoint_info(const std::string& reason,
                                             const FrameCounters& counters) const {
  CheckpointInfo info;
  info.reason = reason;
  info.last_frame_id = last_frame_id_;
  info.T_world_cam = last_pose_;
  info.frames_received = counters.received;
  info.frames_fused = frames_fused_;
  info.frames_tracked_only = counters.tracked_only;
  info.frames_lost = counters.lost;
  info.frames_dropped = counters.dropped;
  return info;
}

std::vector<ChunkKey> ScanRecorder::removed_chunks(const PointMap& map) const {
  // Only those: a map that never held a chunk cannot delete it.
  std::vector<ChunkKey> removed;
  for (const ChunkKey& key : resident_at_checkpoint_)
    if (!map.find(key) && !(pager_ && pager_->is_evicted(key))) removed.push_back(key);
  return removed;
}

Status ScanRecorder::checkpoint_failed(const Status& error, uint32_t last_frame_id) {
  const Status st = error.with_context("checkpoint to frame " + std::to_string(last_frame_id) +
                                       " (the previous checkpoint is intact)");
  status_.checkpoint_error = st.to_string();
  status_.checkpoint_error_code = st.code();
  status_.last_checkpoint_failure = st;
  ++status_.checkpoint_failures;
  return note(st);
}

void ScanRecorder::checkpoint_committed(const CheckpointRecord& rec, std::vector<ChunkKey> resident) {
  resident_at_checkpoint_ = std::move(resident);
  // Its transaction deleted the log records of its frames; those still waiting need not be written.
  if (frame_log_) frame_log_->covered_up_to(rec.last_frame_id);
  ++status_.checkpoints_written;
  status_.last_checkpoint = rec;
  status_.last_error_code = StatusCode::kOk;
  status_.last_error.clear();
  status_.checkpoint_error.clear();
  status_.checkpoint_error_code = StatusCode::kOk;
}

bool ScanRecorder::checkpoint_in_flight() const { return writer_ && writer_->busy(); }

bool ScanRecorder::checkpoint_in_background(PointMap* map, const std::string& reason,
                                            const FrameCounters& counters) {
  const int64_t start_ns = steady_ns();
  collect_background(map);
  if (writer_ && writer_->busy()) return false;
  // The checkpoint's frames' keyframes go first: readers list the keyframes up to its frame.
  (void)write_pending_keyframes();
  const int64_t t0_ns = steady_ns();
  CheckpointJob job;
  job.snapshot_ns = t0_ns;
  job.info = checkpoint_info(reason, counters);
  size_t points_shared = 0;
  // Chunk copies share their points: the writer encodes them while fusion goes on, and fusion
  // copies a chunk's points only where it changes them before they are encoded.
  map->for_each_chunk([&](const ChunkKey& key, const Chunk& c) {
    job.resident.push_back(key);
    if (!c.dirty) return;
    job.chunks.emplace_back(key, c);
    job.written.push_back(key);
    points_shared += c.points().size();
  });
  const int64_t shared_ns = steady_ns();
  const size_t chunks_shared = job.written.size();
  job.removed = removed_chunks(*map);
  job.poses.swap(pending_poses_);
  job.corrections.swap(corrections_);
  if (graph_ && !graph_->empty()) job.graph = graph_;
  if (pending_source_) job.pending = pending_source_();
  size_t points_pending = 0;
  const size_t pending_rows = job.pending.size();
  for (const PendingPoints& p : job.pending) points_pending += p.points.size();
  status_.pending_poses = 0;
  if (!writer_) {
    auto connection = store_->another_connection(config_.store);
    if (!connection) {
      not_written(job, connection.status().with_context("opening the checkpoint writer's connection"));
      return true;
    }
    writer_ = std::make_unique<CheckpointWriter>(std::move(connection).value(),
                                                 config_.background_compression_level);
  }
  writer_->start(std::move(job));
  if (pager_) pager_->checkpoint_snapshot();
  const int64_t end_ns = steady_ns();
  status_.last_snapshot_seconds = static_cast<double>(end_ns - t0_ns) * 1e-9;
  // The fusion thread's share of a background checkpoint.
  DF_LOG(Store, Debug) << "checkpoint to frame " << last_frame_id_ << ": " << chunks_shared
                       << " chunks (" << points_shared << " points) shared in "
                       << (shared_ns - t0_ns) / 1000000 << " ms, " << points_pending
                       << " points pending for " << pending_rows
                       << " chunk versions copied, handed over in "
                       << (end_ns - start_ns) / 1000000 << " ms";
  return true;
}

void ScanRecorder::collect_background(PointMap* map, bool clear_dirty) {
  if (!writer_) return;
  std::optional<CheckpointOutcome> out = writer_->take_outcome();
  if (!out) return;
  CheckpointJob& job = out->job;
  if (pager_) pager_->checkpoint_done(out->record.is_ok());
  status_.last_encode_seconds = out->encode_seconds;
  DF_LOG(Store, Debug) << "checkpoint to frame " << job.info.last_frame_id << ": "
                       << job.written.size() << " chunks encoded in "
                       << static_cast<int>(out->encode_seconds * 1e3) << " ms ("
                       << out->encoded_bytes / 1048576 << " MiB held until written), "
                       << out->chunks_parted << " of them changed (copied) or evicted meanwhile";
  status_.last_write_seconds = out->write_seconds;
  status_.total_encode_seconds += out->encode_seconds;
  status_.total_write_seconds += out->write_seconds;
  if (!out->record) {
    not_written(job, out->record.status());
    return;
  }
  // A chunk a later frame touched has changes the checkpoint does not hold: it stays dirty.
  for (const ChunkKey& key : job.written) {
    Chunk* c = map->find(key);
    if (clear_dirty && c && c->last_touched_frame <= job.info.last_frame_id) c->dirty = false;
  }
  status_.last_checkpoint_chunks = job.written.size();
  status_.last_checkpoint_seconds = static_cast<double>(steady_ns() - job.snapshot_ns) * 1e-9;
  checkpoint_committed(*out->record, std::move(job.resident));
}

// Nothing of the job was written: its poses are pending again, its chunks are still dirty (or were
// staged dirty since), and the removed ones are found again from the last checkpoint's keys.
void ScanRecorder::not_written(const CheckpointJob& job, const Status& why) {
  pending_poses_.insert(pending_poses_.begin(), job.poses.begin(), job.poses.end());
  corrections_.insert(corrections_.begin(), job.corrections.begin(), job.corrections.end());
  status_.pending_poses = pending_poses_.size();
  (void)checkpoint_failed(why, job.info.last_frame_id);
}

Result<CheckpointRecord> ScanRecorder::write_checkpoint(PointMap* map, const std::string& reason,
                                                        const FrameCounters& counters,
                                                        bool postfilter_evicted) {
  if (writer_) writer_->wait_idle();
  // This checkpoint writes every dirty chunk anyway, and finish() comes after a post-filter that
  // changed chunks without touching a frame: none is taken for clean here.
  collect_background(map, /*clear_dirty=*/false);
  (void)write_pending_keyframes();
  const int64_t t0_ns = steady_ns();
  ScanStore& store = *store_;
  Status st = store.begin_checkpoint();
  if (!st) return checkpoint_failed(st, last_frame_id_);
  std::vector<ChunkKey> emptied_evicted;
  size_t written = 0;
  auto body = [&]() -> Status {
    map->for_each_chunk([&](const ChunkKey& key, const Chunk& c) {
      if (st && c.dirty) {
        st = store.write_chunk(key, c);
        ++written;
      }
    });
    DF_RETURN_IF_ERROR(st);
    for (const ChunkKey& key : removed_chunks(*map)) DF_RETURN_IF_ERROR(store.delete_chunk(key));
    if (postfilter_evicted && pager_) {
      // The post-filter is per point, so applying it chunk by chunk equals applying it to the
      // whole map; only one evicted chunk is in memory at a time.
      for (const ChunkKey& key : pager_->evicted()) {
        auto stored = store.read_chunk(key, /*include_staged=*/true);
        if (!stored) {
          if (stored.status().code() == StatusCode::kNotFound) continue;
          return stored.status();
        }
        PointMap one(map->chunk_size_m());
        one.insert(key, std::move(stored->chunk));
        if (postfilter(&one) > 0) {
          const Chunk* c = one.find(key);
          DF_RETURN_IF_ERROR(store.write_chunk(key, *c));
          if (c->points().empty()) emptied_evicted.push_back(key);
        }
      }
    }
    DF_RETURN_IF_ERROR(store.write_poses(
        pending_poses_, corrections_,
        graph_ && !graph_->empty() ? graph_->graph.keyframes : std::vector<GraphKeyframe>{}));
    if (graph_ && !graph_->empty()) DF_RETURN_IF_ERROR(store.write_graph(*graph_));
    DF_RETURN_IF_ERROR(
        store.write_pending(pending_source_ ? pending_source_() : std::vector<PendingPoints>{}));
    return Status::ok();
  };
  st = body();
  if (!st) {
    store.rollback_checkpoint();
    return checkpoint_failed(st, last_frame_id_);
  }
  auto rec = store.commit_checkpoint(checkpoint_info(reason, counters));
  if (!rec) return checkpoint_failed(rec.status(), last_frame_id_);
  std::vector<ChunkKey> resident;
  map->for_each_chunk([&](const ChunkKey& k, Chunk& c) {
    c.dirty = false;
    resident.push_back(k);
  });
  for (const ChunkKey& k : emptied_evicted) pager_->forget(k);
  if (pager_) {  // it promoted every staged chunk
    pager_->checkpoint_snapshot();
    pager_->checkpoint_done(true);
  }
  pending_poses_.clear();
  corrections_.clear();
  status_.pending_poses = 0;
  status_.last_checkpoint_chunks = written;
  checkpoint_committed(*rec, std::move(resident));
  // Encoding and writing the chunks freed heap memory that glibc would keep until the pager's next
  // eviction: give it back now, so that resident memory follows the budget through checkpoints too.
  if (pager_ && config_.pager.release_memory_to_os) malloc_trim(0);
  status_.last_checkpoint_seconds = static_cast<double>(steady_ns() - t0_ns) * 1e-9;
  return rec;
}

}  // namespace depthfuse::store
