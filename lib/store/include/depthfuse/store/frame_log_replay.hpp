// Folding a scan file's frame redo log into its cloud without writing the file: what a resume
// would make of a scan that was killed and not resumed, for `depthfuse export` (a reader; works on
// a read-only store). Format: docs/checkpoint-format.md.
#pragma once

#include <cstddef>
#include <memory>
#include <vector>

#include "depthfuse/config.hpp"
#include "depthfuse/point_map.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/store/scan_store.hpp"

namespace depthfuse::store {

struct LogReplay {
  // The chunks the logged frames touched, as after them (loaded from the last checkpoint first);
  // every other chunk is as the file holds it.
  std::unique_ptr<PointMap> map;
  std::vector<PoseRecord> poses;             // of the replayed frames, in frame order
  // The points still waiting for chunks that have not followed the graph's last correction, after
  // the replay (ExportOptions::replacing_pending: the replay may have brought some of those
  // chunks up to date, and taken their points in).
  std::vector<PendingPoints> pending;
  // The first damaged record, if any (kCorrupt naming the frame): the frames before it were
  // replayed, as a resume does.
  Status damaged;
};

// Fuses the log's records after the last checkpoint, in frame order, each at its stored pose, on
// the chunks of the last checkpoint they can touch (the memory pager's look-ahead; staged chunks
// are not read), in the pose graph's version as a resume does. Memory: the chunks the logged
// frames see.
Result<LogReplay> replay_frame_log(ScanStore& store, const ReconstructionConfig& config);

}  // namespace depthfuse::store
