#include "memory_budget.hpp"

#include <cstdio>
#include <string>

#include "depthfuse/base/heap_reserve.hpp"
#include "depthfuse/pipeline.hpp"
#if DEPTHFUSE_FUSION_HAS_STORE
#include "depthfuse/store/scan_recorder.hpp"
#endif

namespace depthfuse::fusiond {

namespace {

constexpr double kMiB = 1024.0 * 1024.0;
// Bytes per pixel: depth as float metres, colour as RGB; on the wire depth is 16-bit counts
// (compressed no larger, as the codec refuses) and colour at most raw RGB.
constexpr double kDepthBytes = sizeof(float), kColorBytes = 3, kWireDepthBytes = 2;

}  // namespace

MemoryBudget MemoryBudget::of(const AppConfig& config) {
  const auto& f = config.fusion;
  const double pixels = static_cast<double>(f.max_frame_width) * f.max_frame_height;
  const double frame = pixels * (kDepthBytes + kColorBytes);
  MemoryBudget b;
  b.total_mib = f.memory_budget_mib;
  b.queue_mib = (f.queue_capacity_frames * frame + static_cast<double>(kPendingColorFrames) * pixels * kColorBytes) / kMiB;
  // Depth and colour messages, each as reassembled from the bus and as the decoded LCM type; the
  // depth codec's inflated bytes and counts, the colour codec's decompressed or JPEG-decoded image
  // and its conversion; the frame being built.
  const double messages = 2 * pixels * (kWireDepthBytes + kColorBytes);
  const double decoding = pixels * (2 * kWireDepthBytes + 2 * kColorBytes);
  b.receive_mib = (messages + decoding + frame) / kMiB;
  b.worker_mib = (frame + pixels * IncrementalReconstructor::kWorkBytesPerPixel +
                  static_cast<double>(IncrementalReconstructor::relocalisation_bytes(
                      config.reconstruction.relocalisation, static_cast<size_t>(pixels)))) /
                 kMiB;
#if DEPTHFUSE_FUSION_HAS_STORE
  store::RecorderConfig rc;
  rc.frame_log_interval_s = f.frame_log_interval_s;
  b.frame_log_mib =
      static_cast<double>(store::RecorderConfig::frame_log_bytes(rc, static_cast<size_t>(pixels))) / kMiB;
#endif
  return b;
}

Status MemoryBudget::check() const {
  if (map_mib() > 0) return Status::ok();
  char text[512];
  std::snprintf(text, sizeof text,
                "fusion_daemon.memory_budget_mib = %.1f leaves the map nothing: the per-frame work "
                "alone takes %.1f MiB (queue %.1f, receiving %.1f, fusing %.1f, frame log %.1f); raise "
                "the budget, "
                "or lower fusion_daemon.queue_capacity_frames (--queue) or "
                "max_frame_width/max_frame_height",
                total_mib, frame_work_mib(), queue_mib, receive_mib, worker_mib, frame_log_mib);
  return invalid_argument(text);
}

Status MemoryBudget::check_and_reserve() const {
  if (Status st = check(); !st.is_ok()) return st;
  reserve_heap(static_cast<size_t>(reserve_mib() * (1 << 20)));
  return Status::ok();
}

}  // namespace depthfuse::fusiond
