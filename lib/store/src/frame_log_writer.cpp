// ScanRecorder's frame redo log thread (see frame_log_writer.hpp). It owns its connection to the
// scan file; the fusion thread and the checkpoint writer write on theirs, and SQLite's write lock
// orders the transactions.
#include "frame_log_writer.hpp"

#include <algorithm>
#include <chrono>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"

DF_LOG_CATEGORY(Store)

namespace depthfuse::store {

namespace {
int64_t to_ns(double seconds) { return static_cast<int64_t>(seconds * 1e9); }
// How often a commit asks again for the file while another connection writes (new frames to
// encode wake the thread sooner).
constexpr std::chrono::milliseconds kLockedRetry{5};
}  // namespace

FrameLogWriter::FrameLogWriter(std::unique_ptr<ScanStore> connection,
                               const FrameLogWriterConfig& config)
    : store_(std::move(connection)),
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

int64_t FrameLogWriter::lag_ns(int64_t now_ns) const {
  return uncommitted_.empty() ? 0 : now_ns - uncommitted_.front().second;
}

void FrameLogWriter::push(const PoseRecord& pose, const Frame& frame) {
  std::unique_lock<std::mutex> lock(mu_);
  if (suspended_until_ != 0) {
    suspended_until_ = std::max(suspended_until_, pose.frame_id);
    ++stats_.frames_dropped;
    return;
  }
  // Back-pressure: the thread is this far behind (a loaded machine). Waiting here costs the fused
  // rate what the log's work costs, and keeps both memory and what a crash loses bounded. A
  // failing log (retrying, or suspended) holds nothing up: its frames are the checkpoint's.
  const int64_t max_lag = to_ns(config_.max_lag_s);
  const int64_t t0 = steady_ns();
  bool lagged = false;
  cv_.wait(lock, [&] {
    if (stop_ || suspended_until_ != 0) return true;
    if (raw_.size() >= config_.queue_frames) return false;
    const bool behind = retry_after_ns_ == 0 && lag_ns(steady_ns()) >= max_lag;
    lagged |= behind;
    return !behind;
  });
  const int64_t t1 = steady_ns();
  if (t1 - t0 > 1000000) stats_.waited_seconds += static_cast<double>(t1 - t0) * 1e-9;
  if (t1 - t0 > 20000000)
    DF_LOG(Store, Debug) << "frame " << pose.frame_id << " waited " << (t1 - t0) / 1000000
                         << " ms for the frame log's thread";
  if (lagged) ++stats_.lag_waits;
  if (suspended_until_ != 0) {
    suspended_until_ = std::max(suspended_until_, pose.frame_id);
    ++stats_.frames_dropped;
    return;
  }
  Raw r;
  r.pose = pose;
  r.frame.utime = frame.utime;
  r.frame.intrinsics = frame.intrinsics;
  r.frame.depth = frame.depth;
  r.frame.color = frame.color;
  r.pushed_ns = t1;
  uncommitted_.emplace_back(pose.frame_id, t1);
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

void FrameLogWriter::settled_up_to(uint32_t frame_id) {
  while (!uncommitted_.empty() && uncommitted_.front().first <= frame_id) uncommitted_.pop_front();
}

void FrameLogWriter::drop_up_to(uint32_t frame_id) {
  while (!raw_.empty() && raw_.front().pose.frame_id <= frame_id) raw_.pop_front();
  while (!encoded_.empty() && encoded_.front().record.pose.frame_id <= frame_id) {
    encoded_bytes_ -= encoded_.front().record.depth.size() + encoded_.front().record.color.size();
    encoded_.pop_front();
  }
  settled_up_to(frame_id);
}

void FrameLogWriter::covered_up_to(uint32_t frame_id) {
  std::lock_guard<std::mutex> lock(mu_);
  drop_up_to(frame_id);
  covered_up_to_ = std::max(covered_up_to_, frame_id);
  if (suspended_until_ != 0 && frame_id >= suspended_until_) suspended_until_ = 0;
  cv_.notify_all();
}

bool FrameLogWriter::writing() const {
  std::lock_guard<std::mutex> lock(mu_);
  return writing_;
}

FrameLogStats FrameLogWriter::stats() const {
  std::lock_guard<std::mutex> lock(mu_);
  FrameLogStats s = stats_;
  s.frames_waiting = uncommitted_.size();
  s.encoded_bytes_waiting = encoded_bytes_;
  s.lag_seconds = static_cast<double>(lag_ns(steady_ns())) * 1e-9;
  return s;
}

void FrameLogWriter::encode_one(std::unique_lock<std::mutex>& lock) {
  Raw r = std::move(raw_.front());
  raw_.pop_front();
  encoding_ = true;
  cv_.notify_all();  // push() may be waiting for room
  lock.unlock();
  const int64_t t0 = steady_ns(), c0 = thread_cpu_ns();
  Encoded e;
  e.pushed_ns = r.pushed_ns;
  const Status st = encode_frame_log_record(codec_, r.pose, r.frame, &e.record);
  const int64_t t1 = steady_ns(), c1 = thread_cpu_ns();
  lock.lock();
  encoding_ = false;
  stats_.encode_seconds += static_cast<double>(t1 - t0) * 1e-9;
  stats_.cpu_seconds += static_cast<double>(c1 - c0) * 1e-9;
  if (!st) {
    // A fused frame that cannot be logged is a hole: nothing after it can be replayed.
    stats_.last_error = st;
    ++stats_.failures;
    suspended_until_ = std::max(suspended_until_, r.pose.frame_id);
    raw_.clear();
    uncommitted_.clear();
  } else if (suspended_until_ == 0 && r.pose.frame_id > covered_up_to_) {
    // (A checkpoint that covered the frame while it was being encoded made it needless.)
    encoded_bytes_ += e.record.depth.size() + e.record.color.size();
    encoded_.push_back(std::move(e));
  }
}

void FrameLogWriter::put_back(std::vector<FrameLogRecord>& batch, const std::vector<int64_t>& pushed) {
  // (Those a checkpoint covered meanwhile need not be written any more.)
  for (size_t i = batch.size(); i-- > 0 && batch[i].pose.frame_id > covered_up_to_;) {
    encoded_bytes_ += batch[i].depth.size() + batch[i].color.size();
    encoded_.push_front(Encoded{std::move(batch[i]), pushed[i]});
  }
}

bool FrameLogWriter::commit(std::unique_lock<std::mutex>& lock) {
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
  const int64_t t0 = steady_ns(), c0 = thread_cpu_ns();
  const Status st = store_->append_frame_log(batch);
  const int64_t t1 = steady_ns(), c1 = thread_cpu_ns();
  lock.lock();
  writing_ = false;
  stats_.write_seconds += static_cast<double>(t1 - t0) * 1e-9;
  stats_.cpu_seconds += static_cast<double>(c1 - c0) * 1e-9;
  // Another connection's transaction has the file (a checkpoint, the fusion thread's eviction or
  // keyframe): not a failure. The batch goes back and encoding goes on meanwhile, up to twice
  // commit_bytes (otherwise the raw frames pile up and push() holds up the fusion thread for as
  // long as the other transaction); a file locked for locked_timeout_s counts as a failure.
  const bool locked = st.code() == StatusCode::kUnavailable;
  if (locked && locked_since_ns_ == 0) locked_since_ns_ = t1;
  const bool give_up = locked && t1 - locked_since_ns_ >= to_ns(config_.locked_timeout_s);
  if (st) {
    ++stats_.commits;
    stats_.frames_logged += batch.size();
    stats_.last_logged_frame = batch.back().pose.frame_id;
    stats_.max_lag_seconds =
        std::max(stats_.max_lag_seconds, static_cast<double>(t1 - pushed.front()) * 1e-9);
    settled_up_to(batch.back().pose.frame_id);
    retry_after_ns_ = 0;
    locked_since_ns_ = 0;
  } else if (locked && !give_up) {
    put_back(batch, pushed);
    return false;
  } else {
    ++stats_.failures;
    stats_.last_error = st;
    retry_after_ns_ = t1 + to_ns(config_.max_lag_s);
    locked_since_ns_ = 0;
    // Kept for the next try, before anything encoded meanwhile; beyond the bound they go, and
    // logging waits for a checkpoint to cover them.
    if (bytes + encoded_bytes_ > 4 * config_.commit_bytes || suspended_until_ != 0) {
      stats_.frames_dropped += batch.size() + encoded_.size();
      uint32_t newest = batch.back().pose.frame_id;
      if (!encoded_.empty()) newest = encoded_.back().record.pose.frame_id;
      suspended_until_ = std::max(suspended_until_, newest);
      encoded_.clear();
      encoded_bytes_ = 0;
      uncommitted_.clear();
    } else {
      put_back(batch, pushed);
    }
  }
  if (flush_requests_ > flushes_done_ && raw_.empty() && (encoded_.empty() || !st)) {
    flush_status_ = st;
    flushes_done_ = flush_requests_;
  }
  cv_.notify_all();
  return true;
}

void FrameLogWriter::run() {
  // Not a background (niced) thread: its work is small (a frame's encoding is a few percent of its
  // fusion) but what a crash loses depends on its being scheduled. At niceness 10 on two busy cores
  // it waited for a core most of the time and fell a second and more behind (docs/results.md,
  // "Issue 36").
  std::unique_lock<std::mutex> lock(mu_);
  for (;;) {
    if (stop_) return;
    // Encoding stops at twice commit_bytes while the log is healthy (a locked file), so that the
    // raw frames hold up fusion; while its appends fail it goes on, up to the bound that drops the
    // records and stops logging, so that a failing log never holds fusion up.
    const bool failing = retry_after_ns_ != 0;
    if (!raw_.empty() && (encoded_bytes_ < 2 * config_.commit_bytes || failing)) {
      encode_one(lock);
      continue;
    }
    const bool flushing = flush_requests_ > flushes_done_;
    if (encoded_.empty()) {
      if (flushing && raw_.empty()) {
        flush_status_ = Status::ok();
        flushes_done_ = flush_requests_;
        cv_.notify_all();
        continue;
      }
      cv_.wait(lock);
      continue;
    }
    const int64_t now = steady_ns();
    // Due at half the lag bound (or at commit_bytes): the commit's own time and a busy machine's
    // scheduling fit in the other half before push() would have to wait.
    const int64_t due =
        std::max(encoded_.front().pushed_ns + to_ns(config_.max_lag_s) / 2, retry_after_ns_);
    if (!flushing && now < due && (encoded_bytes_ < config_.commit_bytes || now < retry_after_ns_)) {
      cv_.wait_for(lock, std::chrono::nanoseconds(due - now));
      continue;
    }
    if (!commit(lock)) cv_.wait_for(lock, kLockedRetry);
  }
}

}  // namespace depthfuse::store
