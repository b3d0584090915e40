// Folding the frame redo log into the cloud in memory (see frame_log_replay.hpp). Runs in the CLI
// (depthfuse export of a scan killed mid-scan) on a read snapshot of its own.
#include "depthfuse/store/frame_log_replay.hpp"

#include "depthfuse/pipeline.hpp"
#include "depthfuse/store/map_pager.hpp"
#include "depthfuse/store/scan_recorder.hpp"

namespace depthfuse::store {

Result<LogReplay> replay_frame_log(ScanStore& store, const ReconstructionConfig& config) {
  ScopedRead snapshot(store);
  DF_RETURN_IF_ERROR(snapshot.status());
  auto meta = store.metadata();
  if (!meta) return meta.status();
  auto last = store.last_checkpoint();
  if (!last) return last.status();
  auto keys = store.list_chunks();
  if (!keys) return keys.status();
  LogReplay out;
  IncrementalReconstructor reconstructor(config);
  reconstructor.reset(std::make_unique<PointMap>(meta->chunk_size_m),
                      *last ? (*last)->last_frame_id + 1 : 1,
                      *last ? (*last)->T_world_cam : std::nullopt);
  // Every chunk of the checkpoint starts "evicted": the pager loads those a frame can touch, as a
  // resume's does, and nothing is evicted again (no update()).
  MapPagerConfig pc;
  pc.read_staged = false;
  pc.release_memory_to_os = false;
  MapPager pager(pc, &store);
  for (const ChunkInfo& c : *keys) pager.mark_evicted(c.key, c.version);
  // The logged frames were fused in the graph's version: the chunks they meet follow the
  // corrections first, and points sent to chunks still in the file wait beside them.
  auto graph = store.read_graph();
  if (!graph) return graph.status();
  auto pending = store.read_pending();
  if (!pending) return pending.status();
  MapDeformation& deformation = reconstructor.deformation();
  DF_RETURN_IF_ERROR(restore_deformation(*graph, std::move(*pending), store.path(), &deformation,
                                         &reconstructor.map()));
  link_pager(&pager, &deformation);
  const Status read = store.for_each_logged_frame([&](LoggedFrame& f) -> Status {
    DF_RETURN_IF_ERROR(pager.prepare(&reconstructor.map(), f.frame, f.pose.T_world_cam, f.pose.frame_id)
                           .with_context("replaying frame " + std::to_string(f.pose.frame_id)));
    DF_RETURN_IF_ERROR(reconstructor.replay(f.frame, f.pose.frame_id, f.pose.T_world_cam));
    out.poses.push_back(f.pose);
    return Status::ok();
  });
  if (!read) {
    // A damaged record ends the replay as it ends a resume's; anything else is an error.
    if (read.code() != StatusCode::kCorrupt) return read;
    out.damaged = read;
  }
  out.pending = deformation.pending();
  out.map = std::make_unique<PointMap>(meta->chunk_size_m);
  reconstructor.map().for_each_chunk([&](const ChunkKey& key, Chunk& c) {
    out.map->insert(key, std::move(c));
  });
  return out;
}

}  // namespace depthfuse::store
