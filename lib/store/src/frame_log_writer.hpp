// Internal: ScanRecorder's frame redo log thread. The fusion thread hands over each fused frame
// (a copy of its depth and colour, and the pose it was fused at); this thread encodes it at once
// (the keyframe blob codec, lossless) and appends what it has encoded to the scan file's frame_log
// in one transaction (FULL sync) once the oldest waiting frame is commit_interval_s old, or the
// encoded frames reach commit_bytes. Its cost is per frame, whatever the map's size.
//
// Memory is bounded: at most queue_frames raw frames wait for encoding (push() waits when the
// thread is that far behind), and at most about 2 x commit_bytes of encoded frames (waiting, and
// in the transaction). A failed append keeps its records for the next try; when they would exceed
// 4 x commit_bytes they are dropped, and logging stops until a full checkpoint covers every
// dropped frame (a log with a hole cannot be replayed; the checkpoint makes the hole irrelevant).
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "depthfuse/status.hpp"
#include "depthfuse/store/blob_codec.hpp"
#include "depthfuse/store/scan_recorder.hpp"
#include "depthfuse/store/scan_store.hpp"

namespace depthfuse::store {

struct FrameLogWriterConfig {
  double commit_interval_s = 1.0;
  size_t queue_frames = 1;
  size_t commit_bytes = 1u << 20;
  int compression_level = 1;
  int color_compression_level = -5;
};

class FrameLogWriter {
 public:
  // `store_mutex` guards `store`: held only for the append transaction.
  FrameLogWriter(ScanStore* store, std::mutex* store_mutex, const FrameLogWriterConfig& config);
  // Stops without committing what waits: a recorder destroyed without finish() is a crash, and
  // finish()'s checkpoint holds every frame anyway.
  ~FrameLogWriter();
  FrameLogWriter(const FrameLogWriter&) = delete;
  FrameLogWriter& operator=(const FrameLogWriter&) = delete;

  // Copies the frame; waits while queue_frames frames wait for encoding. The caller must not hold
  // the store mutex.
  void push(const PoseRecord& pose, const Frame& frame);
  // Commits everything pushed so far and returns the outcome. The caller must not hold the store
  // mutex.
  Status flush();
  // A full checkpoint of frames up to `frame_id` committed: their records need not be written.
  void covered_up_to(uint32_t frame_id);
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
  // With mu_ held: drops encoded and raw frames up to `frame_id`.
  void drop_up_to(uint32_t frame_id);

  ScanStore* store_;
  std::mutex* store_mutex_;
  FrameLogWriterConfig config_;
  BlobCodec codec_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::deque<Raw> raw_;
  std::deque<Encoded> encoded_;
  uint64_t encoded_bytes_ = 0;
  bool encoding_ = false, writing_ = false;   // the thread holds a frame / a batch outside mu_
  uint64_t flush_requests_ = 0, flushes_done_ = 0;
  Status flush_status_;
  // Logging stopped after dropped records, until a checkpoint covers this frame (0: logging).
  uint32_t suspended_until_ = 0;
  int64_t retry_after_ns_ = 0;
  FrameLogStats stats_;
  bool stop_ = false;
  std::thread thread_;
};

}  // namespace depthfuse::store
