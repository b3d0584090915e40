// Replaying a scan file's frame redo log from the CLI (see frame_log_fold.hpp).
#include "frame_log_fold.hpp"

#include "depthfuse/app_config.hpp"
#include "depthfuse/pipeline.hpp"
#include "depthfuse/store/scan_recorder.hpp"

namespace depthfuse::cli {

Result<ReconstructionConfig> stored_reconstruction_config(store::ScanStore& scan) {
  auto text = scan.config_toml();
  if (!text) return text.status();
  if (!*text || (*text)->empty()) return ReconstructionConfig{};
  auto c = parse_app_config(**text, scan.path() + " (stored configuration)");
  if (!c) return c.status().with_context("the scan's stored configuration does not load");
  return c->reconstruction;
}

Result<size_t> fold_frame_log(const std::string& path) {
  store::ResumePoint at;
  auto rec = store::ScanRecorder::resume(path, store::RecorderConfig{}, &at);
  if (!rec) return rec.status();
  auto config = stored_reconstruction_config((*rec)->store());
  if (!config) return config.status();
  IncrementalReconstructor reconstructor(*config);
  reconstructor.reset(std::move(at.map), at.next_frame_id, at.last_T_world_cam);
  // As the fusion daemon resumes: the logged frames are fused in the graph's version, and the
  // checkpoint keeps the graph, the history and the points waiting for their chunks.
  DF_RETURN_IF_ERROR(store::restore_deformation(at.graph, std::move(at.pending), path,
                                                &reconstructor.deformation(),
                                                &reconstructor.map()));
  (*rec)->set_pending_points([&reconstructor] { return reconstructor.deformation().pending(); });
  if (store::MapPager* pager = (*rec)->pager())
    store::link_pager(pager, &reconstructor.deformation());
  auto replayed = (*rec)->replay_log(reconstructor);
  if (!replayed) return replayed.status();
  if (*replayed == 0) return size_t{0};
  if (at.graph) (*rec)->set_graph({at.graph->graph, reconstructor.deformation().history()});
  auto cp = (*rec)->checkpoint(&reconstructor.map(), "frame log folded",
                               store::frame_counters_of(at.metadata));
  if (!cp) return cp.status();
  return *replayed;
}

}  // namespace depthfuse::cli
