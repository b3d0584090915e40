// depthfuse export: a scan file's cloud to PLY or PCD, streamed chunk by chunk (bounded memory),
// from the last checkpoint; works while the fusion daemon is writing the file. The frames of the
// frame redo log after the last checkpoint (a scan killed and not resumed) are folded in: fused
// in memory on the chunks they touch, which replace the file's. --mesh: a triangle
// mesh of the cloud instead (lib/mesh), which holds the cloud whole and says so when it does not fit.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <vector>
#include <optional>
#include <sstream>

#include "cli_util.hpp"
#include "command.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/mesh/scan_mesh.hpp"
#include "mesh_options.hpp"
#include "depthfuse/store/export.hpp"
#include "depthfuse/store/frame_log_replay.hpp"
#include "depthfuse/store/scan_store.hpp"
#include "frame_log_fold.hpp"

using namespace depthfuse;

DF_LOG_CATEGORY(Export)

namespace {

constexpr const char* kCmd = "export";
constexpr const char* kUsage =
    "depthfuse export <scan.db> -o out.ply|out.pcd [--min-merges N]\n"
    "         [--bbox x0,y0,z0,x1,y1,z1] [--no-color] [--no-stats] [--trajectory FILE]\n"
    "         [--skip-damaged]\n"
    "       depthfuse export <scan.db> --mesh -o mesh.ply [--min-merges N] [--bbox ...] [--no-color]\n"
    "         [--skip-damaged] [--mesh-depth N] [--mesh-trim F] [--mesh-memory-mb N]";

bool parse_bbox(const std::string& text, Eigen::AlignedBox3f* out, std::string* err) {
  double v[6];
  std::istringstream in(text);
  std::string field;
  int n = 0;
  while (std::getline(in, field, ',')) {
    char* end = nullptr;
    if (n >= 6) break;
    v[n] = std::strtod(field.c_str(), &end);
    if (field.empty() || *end || !std::isfinite(v[n])) {
      *err = "--bbox: '" + field + "' is not a number";
      return false;
    }
    ++n;
  }
  if (n != 6 || in.rdbuf()->in_avail() > 0) {
    *err = "--bbox expects six comma-separated numbers x0,y0,z0,x1,y1,z1, got '" + text + "'";
    return false;
  }
  if (v[0] > v[3] || v[1] > v[4] || v[2] > v[5]) {
    *err = "--bbox: the first corner must be the minimum (x0 <= x1, y0 <= y1, z0 <= z1)";
    return false;
  }
  out->min() = Eigen::Vector3f(v[0], v[1], v[2]);
  out->max() = Eigen::Vector3f(v[3], v[4], v[5]);
  return true;
}

// What the command line asks for, checked before the scan file is opened.
struct Options {
  std::string scan, output;
  store::ExportOptions filters;
  std::optional<mesh::MeshOptions> mesh;  // --mesh
  std::optional<std::string> trajectory;
};

// An option that is missing, malformed or out of range: an invalid_argument naming it.
Result<Options> parse_options(const cli::Args& args) {
  if (args.positional().size() != 1 || !args.has("output"))
    return invalid_argument("expected one scan file and -o out.ply|out.pcd");
  Options o;
  o.scan = args.positional()[0];
  o.output = args.get("output");
  long min_merges = 0;
  std::string err;
  if (!args.get_int("min-merges", &min_merges, &err, daemon::closed(0, 65535)))
    return invalid_argument(err);
  o.filters.min_merges = static_cast<uint32_t>(min_merges);
  if (args.has("bbox")) {
    Eigen::AlignedBox3f box;
    if (!parse_bbox(args.get("bbox"), &box, &err)) return invalid_argument(err);
    o.filters.bbox_m = box;
  }
  o.filters.with_color = !args.has("no-color");
  o.filters.with_fusion_stats = !args.has("no-stats");
  o.filters.skip_damaged = args.has("skip-damaged");
  if (args.has("trajectory")) o.trajectory = args.get("trajectory");
  if (const std::string stray = cli::mesh_option_without_mesh(args); !stray.empty())
    return invalid_argument("unknown option --" + stray + " (without --mesh)");
  if (!args.has("mesh")) {
    DF_RETURN_IF_ERROR(store::cloud_format_for(o.output).status());
    return o;
  }
  mesh::MeshOptions mesh_options;
  if (!cli::parse_mesh_options(args, &mesh_options, &err)) return invalid_argument(err);
  mesh_options.with_color = o.filters.with_color;
  if (args.has("no-stats") || args.has("trajectory"))
    return invalid_argument("--no-stats and --trajectory are for cloud exports, not --mesh");
  DF_RETURN_IF_ERROR(cli::check_mesh_path(o.output));
  o.mesh = mesh_options;
  return o;
}

int export_mesh(const Options& o) {
  auto opened = store::ScanStore::open(o.scan, store::OpenMode::kReadOnly);
  if (!opened) return cli::fail(opened.status().message());
  // The mesh reads the file's chunks itself: logged frames would be left out without a word.
  auto log = (*opened)->frame_log_summary();
  if (!log) return cli::fail(log.status().message());
  if (log->count > 0)
    return cli::fail(o.scan + ": " + std::to_string(log->count) +
                     " frames of the frame redo log (" + std::to_string(log->first_frame_id) + "-" +
                     std::to_string(log->last_frame_id) +
                     ") are not in a checkpoint, and a mesh would leave them out; fold them in "
                     "first: depthfuse inspect --fold-log " + o.scan);
  const auto t0 = std::chrono::steady_clock::now();
  mesh::MeshReport report;
  std::vector<std::string> damaged;
  auto m = mesh::mesh_scan(**opened, o.filters, *o.mesh, &report, &damaged);
  for (const std::string& d : damaged) DF_LOG(Export, Warning) << "skipped: " << d;
  if (!m) return cli::fail(m.status().message());
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  auto line = cli::write_mesh(o.output, *m, report, seconds);
  if (!line) return cli::fail(line.status().message());
  std::fputs(line->c_str(), stdout);
  if (!damaged.empty()) {
    DF_LOG(Export, Error) << damaged.size() << " damaged chunks were left out";
    return 1;
  }
  return 0;
}

// Frames after the last checkpoint that the redo log holds (killed, not resumed): replayed here
// as a resume would, so that the export loses none of them. Nothing when the log is empty.
Result<std::optional<store::LogReplay>> fold_log(store::ScanStore& scan) {
  auto log = scan.frame_log_summary();
  if (!log) return log.status();
  if (log->count == 0) return std::optional<store::LogReplay>();
  const std::string how = " (resuming the scan, or depthfuse inspect --fold-log " + scan.path() +
                          ", folds them into the file)";
  auto config = cli::stored_reconstruction_config(scan);
  if (!config) return Status(config.status().code(), config.status().message() + how);
  auto replay = store::replay_frame_log(scan, *config);
  if (!replay)
    return Status(replay.status().code(), "folding the frame redo log of " + scan.path() + ": " +
                                              replay.status().message() + how);
  if (!replay->damaged)
    DF_LOG(Export, Warning) << replay->damaged.message()
                            << ": the frame log is folded in up to the record before it";
  DF_LOG(Export, Info) << "folded in " << replay->poses.size() << " frames of the frame redo log ("
                       << log->first_frame_id << "-" << log->last_frame_id
                       << ") after the last checkpoint";
  return std::optional<store::LogReplay>(std::move(replay).value());
}

int export_points(Options o) {
  auto opened = store::ScanStore::open(o.scan, store::OpenMode::kReadOnly);
  if (!opened) return cli::fail(opened.status().message());
  store::ScanStore& scan = **opened;
  store::ScopedRead snapshot(scan);
  if (!snapshot.status()) return cli::fail(snapshot.status().message());
  auto folded = fold_log(scan);
  if (!folded) return cli::fail(folded.status().message());
  if (*folded) {
    o.filters.replacing = (*folded)->map.get();
    o.filters.replacing_pending = &(*folded)->pending;
  }
  // The trajectory first: a damaged pose (its checksum fails) stops the export before the cloud
  // is written.
  if (o.trajectory) {
    const Status st = store::export_trajectory(
        scan, *o.trajectory, *folded ? (*folded)->poses : std::vector<store::PoseRecord>{});
    if (!st) return cli::fail(st.message() + " (nothing exported)");
  }
  auto report = store::export_cloud(scan, o.output, o.filters);
  if (!report) {
    if (o.trajectory) std::remove(o.trajectory->c_str());
    return cli::fail(report.status().message());
  }
  for (const std::string& d : report->damaged) DF_LOG(Export, Warning) << "skipped: " << d;
  std::printf("wrote %llu points from %zu chunks to %s",
              static_cast<unsigned long long>(report->points_written), report->chunks_read,
              o.output.c_str());
  if (*folded) std::printf(" (%zu logged frames folded in)", (*folded)->poses.size());
  if (report->points_filtered)
    std::printf(" (%llu filtered out)", static_cast<unsigned long long>(report->points_filtered));
  std::printf("\n");
  if (!report->damaged.empty()) {
    DF_LOG(Export, Error) << report->damaged.size() << " damaged chunks were left out";
    return 1;
  }
  return 0;
}

int run(int argc, char** argv) {
  std::vector<std::string> options = {"output", "min-merges", "bbox", "trajectory"};
  options.insert(options.end(), cli::mesh_option_names().begin(), cli::mesh_option_names().end());
  daemon::Startup startup(cli::offline_program(kCmd, kUsage, options,
                                               {"no-color", "no-stats", "skip-damaged", "mesh"}, 1,
                                               false),
                          argc, argv);
  if (auto code = startup.exit_code()) return *code;
  auto o = parse_options(startup.args());
  if (!o) return startup.usage_error(o.status().message());
  return o->mesh ? export_mesh(*o) : export_points(std::move(*o));
}

}  // namespace

DF_REGISTER_COMMAND(export_cmd, kCmd, kUsage,
                    "write a scan file's cloud to PLY or PCD (streaming, works during a scan)", run);
