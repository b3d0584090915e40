// ScanRecorder::restore_keyframes: the relocaliser's keyframes of a resumed scan, rebuilt from the
// keyframes the scan file stores (depth and pose), so that a resumed scan relocalises like one that
// never stopped. Only the keyframes the relocaliser would keep are decoded: the choice is made on
// the poses, which the listing reads without the images.
#include <algorithm>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/store/scan_recorder.hpp"

namespace depthfuse::store {

Result<KeyframeRestoreReport> ScanRecorder::restore_keyframes(IncrementalReconstructor& reconstructor,
                                                              bool load_views) {
  const int64_t t0_ns = steady_ns();
  KeyframeRestoreReport report;
  auto listed = store_->list_keyframes(
      [&](const Status& damaged) { report.skipped.push_back(damaged.to_string()); });
  if (!listed) return listed.status().with_context("restoring relocalisation keyframes");
  std::vector<KeyframeInfo> stored = std::move(listed).value();
  // The listing holds the checkpoint's frames only; a keyframe at or past the reconstructor's next
  // frame would come from a future the map does not hold.
  const uint32_t next = reconstructor.next_frame_id();
  stored.erase(std::remove_if(stored.begin(), stored.end(),
                              [&](const KeyframeInfo& k) { return k.frame_id >= next; }),
               stored.end());
  report.stored = stored.size();

  // Newest first, each one decoded only when the relocaliser wants a keyframe at its pose: a
  // keyframe that fails its checks leaves room for its neighbours. At most max_keyframes are kept,
  // and the decodes are bounded too, should many fail.
  const int max_keyframes = std::max(0, reconstructor.config().relocalisation.max_keyframes);
  const size_t max_decodes = 2 * static_cast<size_t>(max_keyframes);
  PointMap& map = reconstructor.map();
  const uint64_t loaded_before = pager_ ? pager_->stats().total_loaded : 0;
  const double load_below_bytes = pager_ ? config_.pager.memory_budget_mib * 1024.0 * 1024.0 *
                                               config_.pager.low_watermark_fraction
                                         : 0.0;
  for (size_t i = stored.size(); i-- > 0 && report.chosen < max_decodes;) {
    if (!reconstructor.keyframe_wanted(stored[i].T_world_cam)) continue;
    ++report.chosen;
    Result<Keyframe> k = store_->read_keyframe(stored[i].frame_id);
    if (!k) {
      report.skipped.push_back(k.status().to_string());
      continue;
    }
    Frame frame = k->to_frame();
    frame.T_world_cam_hint.reset();
    Result<bool> kept = reconstructor.restore_keyframe(frame, k->T_world_cam, k->frame_id);
    if (!kept) {
      report.skipped.push_back(
          kept.status().with_context(store_->path() + ": keyframe " + std::to_string(k->frame_id))
              .to_string());
      continue;
    }
    if (!*kept) continue;
    ++report.restored;
    report.restored_frames.push_back(k->frame_id);
    // What the keyframe saw, as prepare_frame() would load it for a frame there: verifying a
    // candidate pose tracks against that part of the map. Only under the budget's low watermark,
    // as a scan that never stopped would have it resident only while it fits.
    if (load_views && pager_ && static_cast<double>(map.memory_bytes()) < load_below_bytes) {
      Status st = pager_->prepare(&map, frame, k->T_world_cam, next);
      status_.pager = pager_->stats();
      if (!st) return note(st).with_context("loading the map a restored keyframe sees");
    }
  }
  if (pager_) report.chunks_loaded = static_cast<size_t>(pager_->stats().total_loaded - loaded_before);
  report.seconds = static_cast<double>(steady_ns() - t0_ns) * 1e-9;
  return report;
}

}  // namespace depthfuse::store
