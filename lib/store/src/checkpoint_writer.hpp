// Internal: ScanRecorder's background checkpoints. The fusion thread hands over a snapshot of what
// changed since the last commit (copies of the changed chunks, the chunks that left the map, the
// poses, the checkpoint's frame); the writer's own thread encodes the chunks without holding the
// store, then takes the store's mutex for the one transaction that writes them (WAL, FULL sync).
// One checkpoint at a time: the next snapshot waits for this one's outcome.
#pragma once

#include <condition_variable>
#include <mutex>
#include <optional>
#include <thread>
#include <utility>
#include <vector>

#include "depthfuse/point_map.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/store/blob_codec.hpp"
#include "depthfuse/store/scan_store.hpp"

namespace depthfuse::store {

struct CheckpointJob {
  std::vector<std::pair<ChunkKey, Chunk>> chunks;  // copies of the changed resident chunks
  std::vector<ChunkKey> written;                   // their keys (the copies are freed once encoded)
  std::vector<ChunkKey> removed;                   // left the map since the last checkpoint
  std::vector<ChunkKey> resident;                  // the map's keys at the snapshot
  std::vector<PoseRecord> poses;
  CheckpointInfo info;
  int64_t snapshot_ns = 0;                         // steady clock, when the snapshot was taken
};

struct CheckpointOutcome {
  CheckpointJob job;                               // chunk copies already released
  Result<CheckpointRecord> record = Status::ok();  // the committed checkpoint, or why not
  double encode_seconds = 0.0, write_seconds = 0.0;
};

class CheckpointWriter {
 public:
  // `mutex` guards `store`: the writer holds it only while it writes the transaction.
  CheckpointWriter(ScanStore* store, std::mutex* mutex, int compression_level);
  ~CheckpointWriter();  // finishes the checkpoint in flight, if any
  CheckpointWriter(const CheckpointWriter&) = delete;
  CheckpointWriter& operator=(const CheckpointWriter&) = delete;

  // The caller holds `mutex`. False (and `job` untouched) while the previous one is in flight.
  bool start(CheckpointJob&& job);
  // The caller holds `mutex`: a checkpoint is being encoded or written.
  bool busy() const { return job_.has_value(); }
  // The caller holds `mutex`: the finished checkpoint's outcome, once (empty if none finished).
  std::optional<CheckpointOutcome> take_outcome();
  // The caller holds `mutex` (it is released while waiting): returns once nothing is in flight.
  void wait_idle();

 private:
  void run();

  ScanStore* store_;
  std::mutex* mutex_;
  BlobCodec codec_;
  std::condition_variable cv_;
  std::optional<CheckpointJob> job_;        // in flight
  std::optional<CheckpointOutcome> outcome_;  // finished, not yet taken
  bool stop_ = false;
  std::thread thread_;
};

}  // namespace depthfuse::store
