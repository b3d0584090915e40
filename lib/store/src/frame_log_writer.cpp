// ScanRecorder's frame redo log thread (see frame_log_writer.hpp). It is the third user of the
// scan file besides the fusion thread and the checkpoint writer, always under the store's mutex,
// and only for the append transaction.
#include "frame_log_writer.hpp"

#include <algorithm>
#include <chrono>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/thread_priority.hpp"

namespace depthfuse::store {

namespace {
int64_t to_ns(double seconds) { return static_cast<int64_t>(seconds * 1e9); }
// How often a commit asks again for the store while the checkpoint writer has it (new frames to
// encode wake the thread sooner).
constexpr std::chrono::milliseconds kStoreRetry{5};
}  // namespace

FrameLogWriter::FrameLogWriter(ScanStore* store, std::mutex* store_mutex,
                               const FrameLogWriterConfig& config)
    : store_(store),
      store_mutex_(store_mutex),
      config_(config),
      codec_(config.compression_level, config.color_compression_level),
      thread_([this] { run(); }) {}

FrameLogWriter::~FrameLogWriter() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  thread_.join();
}

void FrameLogWriter::push(const PoseRecord& pose, const Frame& frame) {
  std::unique_lock<std::mutex> lock(mu_);
  if (suspended_until_ != 0) {
    suspended_until_ = std::max(suspended_until_, pose.frame_id);
    ++stats_.frames_dropped;
    return;
  }
  // Back-pressure: the thread is this far behind (a loaded machine); waiting here costs the fused
  // rate what the encoding costs, and memory stays bounded.
  cv_.wait(lock, [&] { return raw_.size() < config_.queue_frames || stop_; });
  Raw r;
  r.pose = pose;
  r.frame.utime = frame.utime;
  r.frame.intrinsics = frame.intrinsics;
  r.frame.depth = frame.depth;
  r.frame.color = frame.color;
  r.pushed_ns = steady_ns();
  raw_.push_back(std::move(r));
  cv_.notify_all();
}

Status FrameLogWriter::flush() {
  std::unique_lock<std::mutex> lock(mu_);
  const uint64_t mine = ++flush_requests_;
  cv_.notify_all();
  cv_.wait(lock, [&] { return flushes_done_ >= mine || stop_; });
  return flush_status_;
}

void FrameLogWriter::drop_up_to(uint32_t frame_id) {
  while (!raw_.empty() && raw_.front().pose.frame_id <= frame_id) raw_.pop_front();
  while (!encoded_.empty() && encoded_.front().record.pose.frame_id <= frame_id) {
    encoded_bytes_ -= encoded_.front().record.depth.size() + encoded_.front().record.color.size();
    encoded_.pop_front();
  }
}

void FrameLogWriter::covered_up_to(uint32_t frame_id) {
  std::lock_guard<std::mutex> lock(mu_);
  drop_up_to(frame_id);
  if (suspended_until_ != 0 && frame_id >= suspended_until_) suspended_until_ = 0;
  cv_.notify_all();
}

FrameLogStats FrameLogWriter::stats() const {
  std::lock_guard<std::mutex> lock(mu_);
  FrameLogStats s = stats_;
  s.frames_waiting = raw_.size() + encoded_.size() + (encoding_ ? 1 : 0);
  s.encoded_bytes_waiting = encoded_bytes_;
  return s;
}

void FrameLogWriter::run() {
  make_background_thread();  // its work has a second of slack, a frame's fusion 33 ms
  std::unique_lock<std::mutex> lock(mu_);
  const int64_t interval_ns = to_ns(config_.commit_interval_s);
  for (;;) {
    if (stop_) return;
    if (!raw_.empty()) {
      Raw r = std::move(raw_.front());
      raw_.pop_front();
      encoding_ = true;
      cv_.notify_all();  // push() may be waiting for room
      lock.unlock();
      const int64_t t0 = steady_ns();
      Encoded e;
      e.pushed_ns = r.pushed_ns;
      const Status st = encode_frame_log_record(codec_, r.pose, r.frame, &e.record);
      const int64_t t1 = steady_ns();
      lock.lock();
      encoding_ = false;
      stats_.encode_seconds += static_cast<double>(t1 - t0) * 1e-9;
      if (!st) {
        // A fused frame that cannot be logged is a hole: nothing after it can be replayed.
        stats_.last_error = st;
        ++stats_.failures;
        suspended_until_ = std::max(suspended_until_, r.pose.frame_id);
        raw_.clear();
      } else if (suspended_until_ == 0) {
        encoded_bytes_ += e.record.depth.size() + e.record.color.size();
        encoded_.push_back(std::move(e));
      }
      continue;
    }
    const bool flushing = flush_requests_ > flushes_done_;
    if (encoded_.empty()) {
      if (flushing) {
        flushes_done_ = flush_requests_;
        cv_.notify_all();
        continue;
      }
      cv_.wait(lock);
      continue;
    }
    const int64_t now = steady_ns();
    const int64_t due = std::max(encoded_.front().pushed_ns + interval_ns, retry_after_ns_);
    if (!flushing && now < due && encoded_bytes_ < config_.commit_bytes) {
      cv_.wait_for(lock, std::chrono::nanoseconds(due - now));
      continue;
    }
    // While the checkpoint writer has the store, encoding goes on instead of waiting for it, up to
    // 2 x commit_bytes encoded (the bound above): otherwise the raw frames pile up and push()
    // holds up the fusion thread for as long as the checkpoint's transaction.
    std::unique_lock<std::mutex> store_lock(*store_mutex_, std::try_to_lock);
    if (!store_lock.owns_lock() && !flushing && encoded_bytes_ < 2 * config_.commit_bytes) {
      cv_.wait_for(lock, kStoreRetry);
      continue;
    }
    std::vector<FrameLogRecord> batch;
    batch.reserve(encoded_.size());
    std::vector<int64_t> pushed;
    for (Encoded& e : encoded_) {
      batch.push_back(std::move(e.record));
      pushed.push_back(e.pushed_ns);
    }
    encoded_.clear();
    const uint64_t bytes = encoded_bytes_;
    encoded_bytes_ = 0;
    writing_ = true;
    lock.unlock();
    const int64_t t0 = steady_ns();
    if (!store_lock.owns_lock()) store_lock.lock();
    const Status st = store_->append_frame_log(batch);
    store_lock.unlock();
    const int64_t t1 = steady_ns();
    lock.lock();
    writing_ = false;
    stats_.write_seconds += static_cast<double>(t1 - t0) * 1e-9;
    if (st) {
      ++stats_.commits;
      stats_.frames_logged += batch.size();
      stats_.last_logged_frame = batch.back().pose.frame_id;
      retry_after_ns_ = 0;
    } else {
      ++stats_.failures;
      stats_.last_error = st;
      retry_after_ns_ = t1 + interval_ns;
      // Kept for the next try, before anything encoded meanwhile; beyond the bound they go, and
      // logging waits for a checkpoint to cover them.
      if (bytes + encoded_bytes_ > 4 * config_.commit_bytes || suspended_until_ != 0) {
        stats_.frames_dropped += batch.size() + encoded_.size();
        uint32_t newest = batch.back().pose.frame_id;
        if (!encoded_.empty()) newest = encoded_.back().record.pose.frame_id;
        suspended_until_ = std::max(suspended_until_, newest);
        encoded_.clear();
        encoded_bytes_ = 0;
      } else {
        for (size_t i = batch.size(); i-- > 0;)
          encoded_.push_front(Encoded{std::move(batch[i]), pushed[i]});
        encoded_bytes_ += bytes;
      }
    }
    if (flushing && (raw_.empty() && (encoded_.empty() || !st))) {
      flush_status_ = st;
      flushes_done_ = flush_requests_;
    }
    cv_.notify_all();
  }
}

}  // namespace depthfuse::store
