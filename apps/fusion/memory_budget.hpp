// What fusion_daemon.memory_budget_mib holds: the per-frame work first, bounded by the largest frame
// the daemon takes (max_frame_width x max_frame_height) and by its queue, and the fused map in the
// rest, which the map pager keeps to. A budget that leaves the map nothing is refused at start.
#pragma once

#include <algorithm>
#include <cstddef>

#include "depthfuse/app_config.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse::fusiond {

// Colour frames the receive thread keeps until their depth frame arrives.
inline constexpr size_t kPendingColorFrames = 8;

struct MemoryBudget {
  double total_mib = 0;
  // queue_capacity_frames decoded frames, and the colour frames waiting for their depth frame.
  double queue_mib = 0;
  // The receive thread's one depth and one colour frame: the messages as received and decoded,
  // their decompression and image decoding buffers, the frame being built.
  double receive_mib = 0;
  // The worker's frame: the frame itself, and what fusing it holds besides the map
  // (IncrementalReconstructor::kWorkBytesPerPixel).
  double worker_mib = 0;
  // The scan file's frame redo log: raw frames waiting for its thread, encoded ones waiting for
  // their commit (store::RecorderConfig::frame_log_bytes). 0 without the log.
  double frame_log_mib = 0;

  static MemoryBudget of(const AppConfig& config);

  double frame_work_mib() const { return queue_mib + receive_mib + worker_mib + frame_log_mib; }
  double map_mib() const { return total_mib - frame_work_mib(); }
  // What the daemon takes from the kernel at start and keeps (reserve_heap()): the per-frame work,
  // and as much again for the map's first frames, within the budget.
  double reserve_mib() const { return std::min(total_mib, 2.0 * frame_work_mib()); }
  // An error naming the figures and the settings when the per-frame work leaves the map nothing.
  Status check() const;
  // check(), then reserve_mib() taken from the kernel (reserve_heap()): what a process that runs
  // the scan does before any of its threads starts.
  Status check_and_reserve() const;
};

}  // namespace depthfuse::fusiond
