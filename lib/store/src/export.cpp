// Exporting a scan file's cloud (PLY or PCD, through the core's PointCloudWriter) and trajectory.
// Runs in the CLI (depthfuse export) and on the fusion daemon's worker thread (the scan's cloud at
// its end), each on its own read snapshot.
#include "depthfuse/store/export.hpp"

#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <tuple>

#include "depthfuse/map_deformation.hpp"
#include "depthfuse/trajectory.hpp"

namespace depthfuse::store {

Result<CloudFormat> cloud_format_for(const std::string& path) {
  const auto dot = path.find_last_of('.');
  std::string ext = dot == std::string::npos ? "" : path.substr(dot + 1);
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext == "ply") return CloudFormat::kPly;
  if (ext == "pcd") return CloudFormat::kPcd;
  return invalid_argument("output '" + path + "' must end in .ply or .pcd");
}

size_t select_points(const PointArrays& a, const ExportOptions& o, std::vector<uint8_t>* keep) {
  keep->assign(a.size(), 1);
  if (o.min_merges == 0 && !o.bbox_m) return a.size();
  size_t n = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    bool k = a.state[i].merges >= o.min_merges;
    if (k && o.bbox_m) k = o.bbox_m->contains(Eigen::Vector3f(a.position_m[i].x(), a.position_m[i].y(), a.position_m[i].z()));
    (*keep)[i] = k;
    n += k;
  }
  return n;
}

namespace {

// Chunks the scan stored before the last loop closure's correction reached them (evicted, or the
// scan ended first) move with their keyframes as they are read: the deformation as stored.
Status restore_deformation(ScanStore& store, MapDeformation* deformation) {
  auto graph = store.read_graph();
  if (!graph) return graph.status().with_context("exporting " + store.path());
  if (*graph) return deformation->restore((*graph)->deformation);
  return Status::ok();
}

// The replacing map's chunks in key order (written after the file's).
std::vector<ChunkKey> sorted_keys(const PointMap* map) { return map ? map->keys() : std::vector<ChunkKey>{}; }

}  // namespace

Result<ExportReport> export_cloud(ScanStore& store, const std::string& path,
                                  const ExportOptions& options) {
  auto format = cloud_format_for(path);
  if (!format) return format.status();
  ScopedRead snapshot(store);
  DF_RETURN_IF_ERROR(snapshot.status());

  MapDeformation deformation;
  DF_RETURN_IF_ERROR(restore_deformation(store, &deformation));
  auto follow = [&](const ChunkInfo& info, PointArrays& a) {
    if (info.version < deformation.version()) deformation.move_in_place(&a, info.version);
  };

  ExportReport report;
  ChunkFilter filter;
  filter.bbox_m = options.bbox_m;
  if (options.skip_damaged)
    filter.on_damaged = [&](const Status& st) { report.damaged.push_back(st.message()); };

  // Points a correction moved into chunks that had not followed it yet: written after the chunks,
  // moved to the graph's version as stale chunks are.
  std::vector<PendingPoints> pending;
  std::string pending_damage;
  if (options.replacing_pending) {
    pending = *options.replacing_pending;
  } else if (auto read = store.read_pending(); read) {
    pending = std::move(*read);
  } else if (options.skip_damaged) {
    pending_damage = read.status().message();
  } else {
    return read.status().with_context("exporting " + store.path());
  }
  for (PendingPoints& p : pending)
    if (p.version < deformation.version()) deformation.move_in_place(&p.points, p.version);

  // Pass 1: count what will be written (the header needs it). Without filters the rows' counts
  // suffice; pass 2 still checks every blob against its row.
  uint64_t count = 0;
  std::vector<uint8_t> keep;
  const PointMap* replacing = options.replacing;
  auto replaced = [&](const ChunkKey& key) { return replacing && replacing->find(key) != nullptr; };
  const std::vector<ChunkKey> extra = sorted_keys(replacing);
  PointArrays copy;
  // A replacing chunk the fold loaded but did not bring up to date moves as the file's would.
  const auto replacing_points = [&](const ChunkKey& key) {
    const Chunk* c = replacing->find(key);
    copy = c->points();
    if (c->version < deformation.version()) deformation.move_in_place(&copy, c->version);
  };
  for (const ChunkKey& key : extra) {
    replacing_points(key);
    count += select_points(copy, options, &keep);
  }
  for (const PendingPoints& p : pending) count += select_points(p.points, options, &keep);
  if (options.min_merges == 0 && !options.bbox_m && !options.skip_damaged && !replacing) {
    auto chunks = store.list_chunks();
    if (!chunks) return chunks.status();
    for (const ChunkInfo& c : *chunks) count += c.point_count;
  } else {
    DF_RETURN_IF_ERROR(store.for_each_chunk(
        [&](const ChunkInfo& info, PointArrays& a) {
          if (replaced(info.key)) return Status::ok();
          follow(info, a);
          count += select_points(a, options, &keep);
          return Status::ok();
        },
        filter));
    report.damaged.clear();  // pass 2 reports them again
  }
  if (!pending_damage.empty()) report.damaged.push_back(pending_damage);

  PointCloudWriter writer;
  Status st = writer.open(path, *format, CloudFields{options.with_color, options.with_fusion_stats},
                          count);
  if (st) {
    auto write = [&](PointArrays& a) {
      const size_t n = select_points(a, options, &keep);
      ++report.chunks_read;
      report.points_written += n;
      report.points_filtered += a.size() - n;
      if (report.points_written > count)
        return internal_error(store.path() + " changed during the export");
      return writer.write(a, &keep);
    };
    st = store.for_each_chunk(
        [&](const ChunkInfo& info, PointArrays& a) {
          if (replaced(info.key)) return Status::ok();
          follow(info, a);
          return write(a);
        },
        filter);
    for (size_t i = 0; i < extra.size() && st; ++i) {
      replacing_points(extra[i]);
      if (!copy.empty()) st = write(copy);
    }
    for (size_t i = 0; i < pending.size() && st; ++i) st = write(pending[i].points);
  }
  Status closed = writer.finish();
  if (st) st = closed;
  if (!st) {
    ::unlink(path.c_str());
    return st.with_context("exporting " + store.path() + " to " + path);
  }
  return report;
}

Status export_trajectory(ScanStore& store, const std::string& path,
                         const std::vector<PoseRecord>& logged) {
  auto poses = store.read_poses();
  if (!poses) return poses.status();
  std::vector<StampedPose> out;
  out.reserve(poses->size() + logged.size());
  for (const PoseRecord& p : *poses) out.push_back({p.utime * 1e-6, p.T_world_cam});
  for (const PoseRecord& p : logged) out.push_back({p.utime * 1e-6, p.T_world_cam});
  return write_tum_trajectory(path, out);
}

}  // namespace depthfuse::store
