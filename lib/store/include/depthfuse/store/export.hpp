// Exports the cloud of a scan file to PLY or PCD, chunk by chunk: memory holds one chunk at a
// time. Both passes (count, then write) run in one read snapshot, so the export is consistent
// while the daemon keeps writing, and it shows the last checkpoint.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "depthfuse/point_cloud_writer.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/store/scan_store.hpp"

namespace depthfuse::store {

// From the file name: .ply or .pcd (case-insensitive).
Result<CloudFormat> cloud_format_for(const std::string& path);

struct ExportOptions {
  uint32_t min_merges = 0;                   // keep points merged at least this often
  std::optional<Eigen::AlignedBox3f> bbox_m; // keep points inside this box (world frame)
  bool with_color = true;
  bool with_fusion_stats = true;             // merges, violations, uncertainty_m
  bool skip_damaged = false;                 // salvage: leave out chunks that fail their checks
  // Chunks that replace the file's chunks of the same keys, or add to them: the frame redo log
  // folded in (replay_frame_log) for a scan killed and not resumed. Not owned.
  const PointMap* replacing = nullptr;
  // With `replacing`: the points waiting for their chunks after the fold (LogReplay::pending),
  // which replace the file's. Not owned.
  const std::vector<PendingPoints>* replacing_pending = nullptr;
};

// Marks in *keep the points of `a` that pass the filters (min_merges, bbox_m); returns how many.
// The export and the mesh (lib/mesh) choose their points with it.
size_t select_points(const PointArrays& a, const ExportOptions& o, std::vector<uint8_t>* keep);

struct ExportReport {
  uint64_t points_written = 0;
  uint64_t points_filtered = 0;              // in the chunks read, removed by the filters
  size_t chunks_read = 0;
  std::vector<std::string> damaged;          // skipped chunks (skip_damaged only)
};

// On failure the partly written output file is removed.
Result<ExportReport> export_cloud(ScanStore& store, const std::string& path,
                                  const ExportOptions& options = {});

// The poses of the last checkpoint as a TUM trajectory (timestamps from utime), then `logged`
// (the frame redo log's, LogReplay::poses).
Status export_trajectory(ScanStore& store, const std::string& path,
                         const std::vector<PoseRecord>& logged = {});

}  // namespace depthfuse::store
