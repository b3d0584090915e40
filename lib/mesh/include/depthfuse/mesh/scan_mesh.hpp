// A scan file's mesh: its cloud (last checkpoint, export's filters) read chunk by chunk into one
// cloud, then meshed whole (surface_mesh.hpp), so no seam runs along chunk borders. The cloud's
// own memory is checked against the budget before it is read, Poisson's before it runs.
#pragma once

#include "depthfuse/mesh/surface_mesh.hpp"
#include "depthfuse/store/export.hpp"
#include "depthfuse/store/scan_store.hpp"

namespace depthfuse::mesh {

// Filters: min_merges, bbox_m and skip_damaged as for a cloud export (the other fields do not
// apply). Damaged chunks skipped go to *damaged.
Result<TriangleMesh> mesh_scan(store::ScanStore& scan, const store::ExportOptions& filters,
                               const MeshOptions& options, MeshReport* report,
                               std::vector<std::string>* damaged);

}  // namespace depthfuse::mesh
