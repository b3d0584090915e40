// Internal: ScanRecorder's background checkpoints. The fusion thread hands over a snapshot of what
// changed since the last commit (the changed chunks, their points shared copy-on-write, the chunks
// that left the map, the poses, the checkpoint's frame); a thread of the writer's encodes the chunks, then another writes
// them in one transaction (WAL, FULL sync) on a connection of its own to the scan file. One
// checkpoint at a time: the next snapshot waits for this one's outcome.
//
// Two threads, for their priorities: encoding is most of the work (a few hundred ms of a core) and
// has seconds of slack, so it runs niced and takes the cores' idle time; the transaction is short
// but holds the file's write lock, which the frame log waits for, so it runs at the fusion
// thread's priority (niced, it waited seconds for a core on a busy machine while the log waited
// for it: docs/results.md, "Issue 36").
#pragma once

#include <condition_variable>
#include <memory>
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
  // The changed resident chunks, their points shared with the map's (Chunk::points_for_write()):
  // each is let go once encoded, so that fusion changes it in place again.
  std::vector<std::pair<ChunkKey, Chunk>> chunks;
  std::vector<ChunkKey> written;                   // their keys
  std::vector<ChunkKey> removed;                   // left the map since the last checkpoint
  std::vector<ChunkKey> resident;                  // the map's keys at the snapshot
  std::vector<PoseRecord> poses;
  // Loop closures applied since the last checkpoint, for the poses written before (after `poses`).
  std::vector<PoseCorrection> corrections;
  std::optional<GraphCheckpoint> graph;            // the pose graph at the snapshot
  // The points pending for chunks that had not followed a correction (ScanStore::write_pending).
  std::vector<PendingPoints> pending;
  CheckpointInfo info;
  int64_t snapshot_ns = 0;                         // steady clock, when the snapshot was taken
};

struct CheckpointOutcome {
  CheckpointJob job;                               // its chunks already released
  Result<CheckpointRecord> record = Status::ok();  // the committed checkpoint, or why not
  double encode_seconds = 0.0, write_seconds = 0.0;
  // Of the chunks shared, those the map no longer shared when they were encoded: fusion (or the
  // map's deformation) changed them meanwhile and copied their points first, or they were evicted.
  size_t chunks_parted = 0;
  size_t encoded_bytes = 0;  // the encoded chunks, held until the transaction has written them
};

class CheckpointWriter {
 public:
  // `connection`: the writing thread's own connection to the scan file (used by nothing else).
  CheckpointWriter(std::unique_ptr<ScanStore> connection, int compression_level);
  ~CheckpointWriter();  // finishes the checkpoint in flight, if any
  CheckpointWriter(const CheckpointWriter&) = delete;
  CheckpointWriter& operator=(const CheckpointWriter&) = delete;

  // False (and `job` untouched) while the previous one is in flight.
  bool start(CheckpointJob&& job);
  // A checkpoint is being encoded or written.
  bool busy() const;
  // Its transaction is open: the file's write lock is taken until it commits.
  bool writing() const;
  // The finished checkpoint's outcome, once (empty if none finished).
  std::optional<CheckpointOutcome> take_outcome();
  // Returns once nothing is in flight.
  void wait_idle();

 private:
  void encode_loop();
  void write_loop();

  std::unique_ptr<ScanStore> store_;
  BlobCodec codec_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::optional<CheckpointJob> job_;        // in flight
  // Of job_: its chunks encoded (the encoder is done with it), its transaction open.
  bool encoded_ = false, writing_ = false;
  std::vector<EncodedChunk> encoded_chunks_, encoded_pending_;
  Status encode_status_;
  double encode_seconds_ = 0.0;
  size_t chunks_parted_ = 0, encoded_bytes_ = 0;
  std::optional<CheckpointOutcome> outcome_;  // finished, not yet taken
  bool stop_ = false;
  std::thread encoder_, writer_;
};

}  // namespace depthfuse::store
