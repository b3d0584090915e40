// The map preview for viewers (map_delta_t on DEPTHFUSE_MAP, docs/protocol.md): at
// map_preview.rate_hz, the chunks the fusion touched since the last delta, each decimated to one
// point per cell, with the last pose and the tracking state; a viewer's map_request_t queues every
// chunk once more (a snapshot, in pieces).
//  - Runs on the fusion worker, between frames: tick() returns at once unless a delta is due. A due
//    delta walks the chunk table's headers (touched chunks carry the frame id that touched them)
//    and decimates at most map_preview.max_points_per_delta map points, so its cost does not grow
//    with the map's points; chunks left over wait for the next delta.
//  - Bandwidth: a token bucket of map_preview.max_bytes_per_s; chunks beyond it wait too.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <string>
#include <unordered_set>
#include <utility>
#include <vector>

#include "depthfuse/app_config.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/transport.hpp"
#include "depthfuse/map_delta_t.hpp"
#include "depthfuse/pipeline.hpp"

namespace depthfuse::fusiond {

class MapPreview {
 public:
  // `sender` is the daemon's name (map_request_t.target, map_delta_t.sender).
  MapPreview(const MapPreviewConfig& config, std::string sender, lcm::LcmTransport* lcm);

  // Receive thread: a viewer's map_request_t. What does not decode is counted in *counters.
  void on_request(const uint8_t* data, size_t size, lcm::ReceiveCounters* counters);

  // Worker thread, after a frame was fused.
  void frame_fused(int64_t sequence, const Pose& T_world_cam, bool registered);
  // Every frame processed, fused or not: its TrackingState as map_delta_t::TRACKING_*.
  void frame_tracked(int8_t tracking) { tracking_ = tracking; }
  // Worker thread, once per loop: publishes when a delta is due. `reconstructor` is null when no
  // scan is open; the map is read here, on the thread that writes it.
  void tick(int8_t state, const std::string& scan_id, const IncrementalReconstructor* reconstructor);

  // Any thread: the preview's figures for the heartbeat.
  void add_counters(std::vector<std::pair<std::string, double>>* out) const;

 private:
  using Clock = std::chrono::steady_clock;

  void restart(const std::string& scan_id, const IncrementalReconstructor* reconstructor);
  void queue(const ChunkKey& key);
  // Decimates one chunk into *out; the number of map points it read.
  size_t decimate(const ChunkKey& key, const Chunk& chunk, float chunk_size_m,
                  depthfuse::map_chunk_t* out);
  depthfuse::map_delta_t header(int8_t state, const std::string& scan_id,
                                const IncrementalReconstructor* reconstructor) const;
  void publish(depthfuse::map_delta_t* msg);

  MapPreviewConfig config_;
  std::string sender_;
  lcm::LcmTransport* lcm_;

  // Receive thread -> worker.
  std::atomic<int64_t> requested_snapshot_{0};

  // Worker only.
  std::string scan_id_;
  const IncrementalReconstructor* reconstructor_ = nullptr;
  uint32_t scanned_through_frame_ = 0;  // chunks touched by later frames are due
  std::deque<ChunkKey> pending_;
  std::unordered_set<ChunkKey, ChunkKeyHash> queued_;
  int64_t snapshot_id_ = 0;             // the request being answered, 0 when none
  std::unordered_set<ChunkKey, ChunkKeyHash> snapshot_left_;  // its chunks not sent yet
  bool has_pose_ = false, registered_ = false;
  int8_t tracking_ = 0;
  int64_t frame_sequence_ = 0;
  Pose T_world_cam_ = Pose::Identity();
  int64_t sequence_ = 0;
  Clock::time_point next_delta_{}, last_refill_{};
  double tokens_bytes_ = 0;
  // Scratch of decimate(), kept between calls: per cell of a chunk the generation that last
  // touched it (so that nothing is cleared per chunk), its most certain point and that point's
  // uncertainty; and the cells touched, in order.
  struct Cell {
    uint32_t generation = 0;
    uint32_t best = 0;
    float best_u = 0;
  };
  std::vector<Cell> cells_;
  std::vector<uint32_t> occupied_;
  uint32_t generation_ = 0;

  // Worker writes, heartbeat reads.
  std::atomic<int64_t> bytes_sent_{0}, messages_sent_{0}, snapshots_{0}, chunks_pending_{0};
  std::atomic<int64_t> requests_{0};
  std::atomic<double> bytes_per_s_{0}, tick_ms_mean_{0}, tick_ms_max_{0}, tick_ms_total_{0};
};

}  // namespace depthfuse::fusiond
