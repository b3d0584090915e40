// A scan file's cloud gathered chunk by chunk (in one read snapshot) and meshed whole.
#include "depthfuse/mesh/scan_mesh.hpp"

#include <cstdio>

#include "depthfuse/base/meminfo.hpp"

namespace depthfuse::mesh {

Result<TriangleMesh> mesh_scan(store::ScanStore& scan, const store::ExportOptions& filters,
                               const MeshOptions& options, MeshReport* report,
                               std::vector<std::string>* damaged) {
  store::ScopedRead snapshot(scan);
  DF_RETURN_IF_ERROR(snapshot.status());
  auto chunks = scan.list_chunks();
  if (!chunks) return chunks.status();
  uint64_t stored = 0;
  for (const store::ChunkInfo& c : *chunks) stored += c.point_count;
  // The cloud is held whole while Poisson runs: refuse before reading it if it alone is too big.
  const double cloud_bytes = static_cast<double>(stored) * PointArrays::kBytesPerPoint;
  const size_t budget = options.memory_budget_bytes ? *options.memory_budget_bytes : available_memory_bytes();
  if (budget && cloud_bytes > static_cast<double>(budget)) {
    char gb[64];
    std::snprintf(gb, sizeof gb, "%.2f GB, more than the %.2f GB", cloud_bytes / 1e9,
                  static_cast<double>(budget) / 1e9);
    return invalid_argument(scan.path() + ": holding its " + std::to_string(stored) + " points needs about " + gb +
                            (options.memory_budget_bytes ? " allowed" : " available") +
                            "; mesh a part of it (a bounding box)");
  }

  store::ChunkFilter filter;
  filter.bbox_m = filters.bbox_m;
  if (filters.skip_damaged && damaged)
    filter.on_damaged = [&](const Status& st) { damaged->push_back(st.message()); };
  else if (filters.skip_damaged)
    filter.on_damaged = [](const Status&) {};
  PointArrays cloud;
  cloud.reserve(static_cast<size_t>(stored));
  std::vector<uint8_t> keep;
  DF_RETURN_IF_ERROR(scan.for_each_chunk(
      [&](const store::ChunkInfo&, PointArrays& a) {
        if (store::select_points(a, filters, &keep) < a.size()) a.compact(keep);
        cloud.append(a);
        return Status::ok();
      },
      filter));
  return mesh_points(cloud, options, report);
}

}  // namespace depthfuse::mesh
