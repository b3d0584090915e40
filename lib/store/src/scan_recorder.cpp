// The fusion daemon's use of the store: owns the scan file's writer, the pager and the poses since
// the last checkpoint. Runs on the fusion daemon's worker thread (SqliteCheckpointSink).
#include "depthfuse/store/scan_recorder.hpp"

#include <malloc.h>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/fusion.hpp"

namespace depthfuse::store {

ScanRecorder::ScanRecorder(std::unique_ptr<ScanStore> store, const RecorderConfig& config)
    : store_(std::move(store)), config_(config) {
  status_.path = store_->path();
  if (config_.bounded_memory) pager_ = std::make_unique<MapPager>(config_.pager, store_.get());
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
  return std::unique_ptr<ScanRecorder>(new ScanRecorder(std::move(store).value(), config));
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
    for (const ChunkInfo& c : *keys) rec->pager_->mark_evicted(c.key);
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
      c.points = std::move(points);
      c.last_touched_frame = info.last_touched_frame;
      c.dirty = false;
      map->insert(info.key, std::move(c));
      return Status::ok();
    }));
  }
  if (rec->pager_) rec->status_.pager = rec->pager_->stats();
  return rec;
}

Status ScanRecorder::prepare_frame(const Frame& frame, IncrementalReconstructor& reconstructor,
                                   const std::optional<Pose>& prediction) {
  if (!pager_) return Status::ok();
  Pose guess = Pose::Identity();
  if (frame.T_world_cam_hint) guess = *frame.T_world_cam_hint;
  else if (prediction) guess = *prediction;
  else if (reconstructor.last_pose()) guess = *reconstructor.last_pose();
  Status st = pager_->prepare(&reconstructor.map(), frame, guess, reconstructor.next_frame_id());
  status_.pager = pager_->stats();
  return note(st);
}

Status ScanRecorder::record_frame(const Frame& frame, const FrameReport& report, PointMap* map) {
  PoseRecord p;
  p.frame_id = report.frame_id;
  p.utime = frame.utime;
  p.T_world_cam = report.T_world_cam;
  p.registered = report.registered;
  p.fitness = report.registration.fitness;
  p.rmse_m = report.registration.rmse_m;
  p.correspondences = static_cast<uint32_t>(report.registration.correspondences);
  pending_poses_.push_back(p);
  last_frame_id_ = report.frame_id;
  last_pose_ = report.T_world_cam;
  ++frames_fused_;
  ++status_.frames_recorded;
  status_.pending_poses = pending_poses_.size();

  Status result;
  const int every = config_.keyframe_every_n_frames;
  if (every > 0 && (frames_since_keyframe_ % static_cast<uint64_t>(every)) == 0 &&
      !frame.depth.empty()) {
    Status st = store_->write_keyframe(
        Keyframe::from_frame(frame, report.frame_id, report.T_world_cam, config_.keyframe_color));
    if (st) ++status_.keyframes_written;
    else result = note(st);
  }
  ++frames_since_keyframe_;

  if (pager_) {
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

Result<CheckpointRecord> ScanRecorder::write_checkpoint(PointMap* map, const std::string& reason,
                                                        const FrameCounters& counters,
                                                        bool postfilter_evicted) {
  const int64_t t0_ns = steady_ns();
  ScanStore& store = *store_;
  Status st = store.begin_checkpoint();
  if (!st) {
    status_.checkpoint_error = st.to_string();
    ++status_.checkpoint_failures;
    return note(st);
  }
  std::vector<ChunkKey> emptied_evicted;
  auto body = [&]() -> Status {
    map->for_each_chunk([&](const ChunkKey& key, const Chunk& c) {
      if (st && c.dirty) st = store.write_chunk(key, c);
    });
    DF_RETURN_IF_ERROR(st);
    // Chunks that were in the map at the last checkpoint and have left it without being evicted
    // leave the file too. (Only those: a map that never held a chunk cannot delete it.)
    for (const ChunkKey& key : resident_at_checkpoint_) {
      if (!map->find(key) && !(pager_ && pager_->is_evicted(key)))
        DF_RETURN_IF_ERROR(store.delete_chunk(key));
    }
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
          if (c->points.empty()) emptied_evicted.push_back(key);
        }
      }
    }
    for (const PoseRecord& p : pending_poses_) DF_RETURN_IF_ERROR(store.write_pose(p));
    return Status::ok();
  };
  auto failed = [&](const Status& error) {
    const Status st2 = error.with_context("checkpoint (the previous checkpoint is intact)");
    status_.checkpoint_error = st2.to_string();
    ++status_.checkpoint_failures;
    return note(st2);
  };
  st = body();
  if (!st) {
    store.rollback_checkpoint();
    return failed(st);
  }
  CheckpointInfo info;
  info.reason = reason;
  info.last_frame_id = last_frame_id_;
  info.T_world_cam = last_pose_;
  info.frames_received = counters.received;
  info.frames_fused = frames_fused_;
  info.frames_dropped = counters.dropped;
  auto rec = store.commit_checkpoint(info);
  if (!rec) return failed(rec.status());
  resident_at_checkpoint_.clear();
  map->for_each_chunk([&](const ChunkKey& k, Chunk& c) {
    c.dirty = false;
    resident_at_checkpoint_.push_back(k);
  });
  for (const ChunkKey& k : emptied_evicted) pager_->forget(k);
  pending_poses_.clear();
  status_.pending_poses = 0;
  ++status_.checkpoints_written;
  status_.last_checkpoint = *rec;
  // Encoding and writing the chunks freed heap memory that glibc would keep until the pager's next
  // eviction: give it back now, so that resident memory follows the budget through checkpoints too.
  if (pager_ && config_.pager.release_memory_to_os) malloc_trim(0);
  status_.last_checkpoint_seconds = static_cast<double>(steady_ns() - t0_ns) * 1e-9;
  status_.last_error_code = StatusCode::kOk;
  status_.last_error.clear();
  status_.checkpoint_error.clear();
  return rec;
}

}  // namespace depthfuse::store
