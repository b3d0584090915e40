// Internal: ScanRecorder's frame redo log thread. The fusion thread hands over each fused frame
// (a copy of its depth and colour, and the pose it was fused at); this thread encodes it at once
// (the keyframe blob codec, lossless) and appends what it has encoded to the scan file's frame_log
// in one transaction (FULL sync), on a connection of its own, once the oldest waiting frame is
// half of max_lag_s old, or the encoded frames reach commit_bytes. Its cost is per frame, whatever
// the map's size.
//
// What a crash loses is bounded: push() waits while the oldest frame not yet committed was pushed
// max_lag_s ago or more (a loaded machine that starves this thread holds up fusion instead of
// leaving frames unlogged), unless the log is failing. Memory is bounded: at most queue_frames raw
// frames wait for encoding (push() waits when the thread is that far behind), and at most about
// 2 x commit_bytes of encoded frames (waiting, and in the transaction). A failed append keeps its
// records for the next try; when they would exceed 4 x commit_bytes they are dropped, and logging
// stops until a full checkpoint covers every dropped frame (a log with a hole cannot be replayed;
// the checkpoint makes the hole irrelevant).
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "depthfuse/status.hpp"
#include "depthfuse/store/blob_codec.hpp"
#include "depthfuse/store/scan_recorder.hpp"
#include "depthfuse/store/scan_store.hpp"

namespace depthfuse::store {

struct FrameLogWriterConfig {
  double max_lag_s = 0.9;
  size_t queue_frames = 1;
  size_t commit_bytes = 1u << 20;
  int compression_level = 1;
  int color_compression_level = -5;
  // How long a commit that cannot wait any more waits for another connection's transaction before
  // it counts as failed.
  double locked_timeout_s = 5.0;
};

class FrameLogWriter {
 public:
  // `connection`: the thread's own connection to the scan file, opened without a busy timeout
  // (used by nothing else).
  FrameLogWriter(std::unique_ptr<ScanStore> connection, const FrameLogWriterConfig& config);
  // Stops without committing what waits: a recorder destroyed without finish() is a crash, and
  // finish()'s checkpoint holds every frame anyway.
  ~FrameLogWriter();
  FrameLogWriter(const FrameLogWriter&) = delete;
  FrameLogWriter& operator=(const FrameLogWriter&) = delete;

  // Copies the frame; waits while queue_frames frames wait for encoding, or while the oldest
  // frame not committed is max_lag_s old (unless the last append failed or logging is suspended).
  void push(const PoseRecord& pose, const Frame& frame);
  // Commits everything pushed so far and returns the outcome.
  Status flush();
  // A full checkpoint of frames up to `frame_id` committed: their records need not be written.
  void covered_up_to(uint32_t frame_id);
  // An append's transaction is open (the file's write lock is taken until it commits).
  bool writing() const;
  FrameLogStats stats() const;

 private:
  struct Raw {
    PoseRecord pose;
    Frame frame;
    int64_t pushed_ns = 0;
  };
  struct Encoded {
    FrameLogRecord record;
    int64_t pushed_ns = 0;
  };
  void run();
  // With mu_ held: encodes the oldest raw frame (mu_ released meanwhile).
  void encode_one(std::unique_lock<std::mutex>& lock);
  // With mu_ held: appends every encoded frame in one transaction (mu_ released meanwhile). False
  // when another connection has the file's write lock: the frames wait for the next try.
  bool commit(std::unique_lock<std::mutex>& lock);
  // With mu_ held: a batch that was not committed goes back before what was encoded meanwhile.
  void put_back(std::vector<FrameLogRecord>& batch, const std::vector<int64_t>& pushed);
  // With mu_ held: drops encoded and raw frames up to `frame_id`.
  void drop_up_to(uint32_t frame_id);
  // With mu_ held: frames up to `frame_id` are committed or need not be.
  void settled_up_to(uint32_t frame_id);
  // With mu_ held: the age of the oldest frame pushed and not committed, 0 without one.
  int64_t lag_ns(int64_t now_ns) const;

  std::unique_ptr<ScanStore> store_;
  FrameLogWriterConfig config_;
  BlobCodec codec_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::deque<Raw> raw_;
  std::deque<Encoded> encoded_;
  // Every frame pushed and not yet committed (raw, being encoded, encoded, in the transaction),
  // oldest first: (frame id, when pushed).
  std::deque<std::pair<uint32_t, int64_t>> uncommitted_;
  uint64_t encoded_bytes_ = 0;
  bool encoding_ = false, writing_ = false;   // the thread holds a frame / a batch outside mu_
  uint64_t flush_requests_ = 0, flushes_done_ = 0;
  Status flush_status_;
  // Logging stopped after dropped records, until a checkpoint covers this frame (0: logging).
  uint32_t suspended_until_ = 0;
  uint32_t covered_up_to_ = 0;                // the newest frame a full checkpoint holds
  int64_t retry_after_ns_ = 0;                // after a failed append: when to try again
  int64_t locked_since_ns_ = 0;               // a due commit found the file locked since then
  FrameLogStats stats_;
  bool stop_ = false;
  std::thread thread_;
};

}  // namespace depthfuse::store
