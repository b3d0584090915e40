// The frame redo log of a scan file killed mid-scan, for the CLI: the reconstruction settings the
// scan was fused with (to replay its frames as the daemon would), and folding the log into the
// file (`depthfuse inspect --fold-log`).
#pragma once

#include <cstddef>
#include <string>

#include "depthfuse/config.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/store/scan_store.hpp"

namespace depthfuse::cli {

// The configuration stored in the scan (the daemon's file), or the defaults when it stores none
// (a daemon started without --config fuses with the defaults).
Result<ReconstructionConfig> stored_reconstruction_config(store::ScanStore& scan);

// Opens the scan for writing, replays its logged frames as a resume does and writes a checkpoint
// (reason "frame log folded") that holds them; says how many frames it replayed.
Result<size_t> fold_frame_log(const std::string& path);

}  // namespace depthfuse::cli
