// ScanRecorder's background checkpoints (see checkpoint_writer.hpp). The writing thread owns the
// connection it writes on; the fusion thread sees only the job and its outcome, under mu_.
#include "checkpoint_writer.hpp"

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/thread_priority.hpp"

namespace depthfuse::store {

CheckpointWriter::CheckpointWriter(std::unique_ptr<ScanStore> connection, int compression_level)
    : store_(std::move(connection)),
      codec_(compression_level),
      encoder_([this] { encode_loop(); }),
      writer_([this] { write_loop(); }) {}

CheckpointWriter::~CheckpointWriter() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  encoder_.join();
  writer_.join();
}

bool CheckpointWriter::start(CheckpointJob&& job) {
  std::lock_guard<std::mutex> lock(mu_);
  if (job_) return false;
  job_ = std::move(job);
  outcome_.reset();
  cv_.notify_all();
  return true;
}

bool CheckpointWriter::busy() const {
  std::lock_guard<std::mutex> lock(mu_);
  return job_.has_value();
}

bool CheckpointWriter::writing() const {
  std::lock_guard<std::mutex> lock(mu_);
  return writing_;
}

std::optional<CheckpointOutcome> CheckpointWriter::take_outcome() {
  std::lock_guard<std::mutex> lock(mu_);
  std::optional<CheckpointOutcome> out = std::move(outcome_);
  outcome_.reset();
  return out;
}

void CheckpointWriter::wait_idle() {
  std::unique_lock<std::mutex> lock(mu_);
  cv_.wait(lock, [&] { return !job_; });
}

void CheckpointWriter::encode_loop() {
  make_background_thread();  // its work has seconds of slack, a frame's fusion 33 ms
  std::unique_lock<std::mutex> lock(mu_);
  for (;;) {
    cv_.wait(lock, [&] { return (job_ && !encoded_) || stop_; });
    if (!job_ || encoded_) return;  // stopping, nothing to encode
    CheckpointJob& job = *job_;
    lock.unlock();
    const int64_t t0 = steady_ns();
    std::vector<EncodedChunk> encoded(job.chunks.size());
    Status st;
    size_t parted = 0, bytes = 0;
    for (size_t i = 0; i < job.chunks.size() && st; ++i) {
      Chunk& chunk = job.chunks[i].second;
      st = encode_chunk(codec_, job.chunks[i].first, chunk, &encoded[i]);
      bytes += encoded[i].blob.capacity();
      parted += !chunk.points().empty() && !chunk.points_shared();
      chunk = Chunk();  // fusion need not copy it to change it any more
    }
    std::vector<std::pair<ChunkKey, Chunk>>().swap(job.chunks);
    std::vector<EncodedChunk> pending(job.pending.size());
    for (size_t i = 0; i < job.pending.size() && st; ++i) {
      st = encode_pending(codec_, job.pending[i], &pending[i]);
      bytes += pending[i].blob.capacity();
    }
    std::vector<PendingPoints>().swap(job.pending);
    const int64_t t1 = steady_ns();
    lock.lock();
    encoded_chunks_ = std::move(encoded);
    encoded_pending_ = std::move(pending);
    encode_status_ = st;
    encode_seconds_ = static_cast<double>(t1 - t0) * 1e-9;
    chunks_parted_ = parted;
    encoded_bytes_ = bytes;
    encoded_ = true;
    cv_.notify_all();
  }
}

void CheckpointWriter::write_loop() {
  std::unique_lock<std::mutex> lock(mu_);
  for (;;) {
    // A job being encoded when the writer stops is finished first.
    cv_.wait(lock, [&] { return (job_ && encoded_) || (stop_ && !job_); });
    if (!job_) return;
    CheckpointJob& job = *job_;
    std::vector<EncodedChunk> encoded = std::move(encoded_chunks_);
    std::vector<EncodedChunk> pending = std::move(encoded_pending_);
    Status st = encode_status_;
    writing_ = true;
    lock.unlock();
    const int64_t t1 = steady_ns();
    CheckpointOutcome out;
    if (st) st = store_->begin_checkpoint(job.info.last_frame_id);
    if (st) {
      auto body = [&]() -> Status {
        for (const EncodedChunk& c : encoded) DF_RETURN_IF_ERROR(store_->write_chunk(c));
        for (const ChunkKey& k : job.removed) DF_RETURN_IF_ERROR(store_->delete_chunk(k));
        DF_RETURN_IF_ERROR(store_->write_poses(
            job.poses, job.corrections,
            job.graph ? job.graph->graph.keyframes : std::vector<GraphKeyframe>{}));
        if (job.graph) DF_RETURN_IF_ERROR(store_->write_graph(*job.graph));
        DF_RETURN_IF_ERROR(store_->write_pending(pending));
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
    out.write_seconds = static_cast<double>(steady_ns() - t1) * 1e-9;
    std::vector<EncodedChunk>().swap(encoded);
    std::vector<EncodedChunk>().swap(pending);
    lock.lock();
    out.encode_seconds = encode_seconds_;
    out.chunks_parted = chunks_parted_;
    out.encoded_bytes = encoded_bytes_;
    writing_ = encoded_ = false;
    out.job = std::move(job);
    job_.reset();
    outcome_ = std::move(out);
    cv_.notify_all();
  }
}

}  // namespace depthfuse::store
