// ScanRecorder's background checkpoints (see checkpoint_writer.hpp). The thread started here is
// the only one besides the fusion thread that uses the scan file, always under the store's mutex.
#include "checkpoint_writer.hpp"

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/thread_priority.hpp"

namespace depthfuse::store {

CheckpointWriter::CheckpointWriter(ScanStore* store, std::mutex* mutex, int compression_level)
    : store_(store), mutex_(mutex), codec_(compression_level), thread_([this] { run(); }) {}

CheckpointWriter::~CheckpointWriter() {
  {
    std::lock_guard<std::mutex> lock(*mutex_);
    stop_ = true;
  }
  cv_.notify_all();
  thread_.join();
}

bool CheckpointWriter::start(CheckpointJob&& job) {
  if (job_) return false;
  job_ = std::move(job);
  outcome_.reset();
  cv_.notify_all();
  return true;
}

std::optional<CheckpointOutcome> CheckpointWriter::take_outcome() {
  std::optional<CheckpointOutcome> out = std::move(outcome_);
  outcome_.reset();
  return out;
}

void CheckpointWriter::wait_idle() {
  // The caller already holds the mutex: adopt it for the wait and hand it back held.
  std::unique_lock<std::mutex> lock(*mutex_, std::adopt_lock);
  cv_.wait(lock, [&] { return !job_; });
  lock.release();
}

void CheckpointWriter::run() {
  make_background_thread();  // its work has a second of slack, a frame's fusion 33 ms
  std::unique_lock<std::mutex> lock(*mutex_);
  for (;;) {
    cv_.wait(lock, [&] { return job_.has_value() || stop_; });
    if (!job_) return;  // stopping, nothing in flight
    CheckpointJob& job = *job_;
    // Encoding is most of the work and needs nothing but the copies: the fusion thread keeps the
    // store meanwhile (keyframes, eviction, loading).
    lock.unlock();
    const int64_t t0 = steady_ns();
    std::vector<EncodedChunk> encoded(job.chunks.size());
    Status st;
    for (size_t i = 0; i < job.chunks.size() && st; ++i)
      st = encode_chunk(codec_, job.chunks[i].first, job.chunks[i].second, &encoded[i]);
    std::vector<std::pair<ChunkKey, Chunk>>().swap(job.chunks);
    const int64_t t1 = steady_ns();
    lock.lock();
    CheckpointOutcome out;
    if (st) st = store_->begin_checkpoint(job.info.last_frame_id);
    if (st) {
      auto body = [&]() -> Status {
        for (const EncodedChunk& c : encoded) DF_RETURN_IF_ERROR(store_->write_chunk(c));
        for (const ChunkKey& k : job.removed) DF_RETURN_IF_ERROR(store_->delete_chunk(k));
        for (const PoseRecord& p : job.poses) DF_RETURN_IF_ERROR(store_->write_pose(p));
        return Status::ok();
      };
      st = body();
      if (st) {
        out.record = store_->commit_checkpoint(job.info);
      } else {
        store_->rollback_checkpoint();
      }
    }
    if (!st) out.record = st;
    out.encode_seconds = static_cast<double>(t1 - t0) * 1e-9;
    out.write_seconds = static_cast<double>(steady_ns() - t1) * 1e-9;
    out.job = std::move(job);
    job_.reset();
    outcome_ = std::move(out);
    cv_.notify_all();
  }
}

}  // namespace depthfuse::store
