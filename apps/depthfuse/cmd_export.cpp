// depthfuse export: a scan file's cloud to PLY or PCD, streamed chunk by chunk (bounded memory),
// from the last checkpoint; works while the fusion daemon is writing the file. The frames of the
// frame redo log after the last checkpoint (a scan killed and not resumed) are folded in: fused
// in memory on the chunks they touch, which replace the file's. --mesh: a triangle
// mesh of the cloud instead (lib/mesh), which holds the cloud whole and says so when it does not fit.
#include <chrono>
#include <cmath>
#include <cstdio>
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

int export_mesh(const cli::Args& args, const store::ExportOptions& filters, const std::string& out) {
  mesh::MeshOptions options;
  std::string err;
  if (!cli::parse_mesh_options(args, &options, &err)) return cli::fail(err);
  options.with_color = filters.with_color;
  if (args.has("no-stats") || args.has("trajectory"))
    return cli::fail("--no-stats and --trajectory are for cloud exports, not --mesh");
  if (const Status path_ok = cli::check_mesh_path(out); !path_ok) return cli::fail(path_ok.message());

  auto opened = store::ScanStore::open(args.positional()[0], store::OpenMode::kReadOnly);
  if (!opened) return cli::fail(opened.status().message());
  // The mesh reads the file's chunks itself: logged frames would be left out without a word.
  auto log = (*opened)->frame_log_summary();
  if (!log) return cli::fail(log.status().message());
  if (log->count > 0)
    return cli::fail(args.positional()[0] + ": " + std::to_string(log->count) +
                     " frames of the frame redo log (" + std::to_string(log->first_frame_id) + "-" +
                     std::to_string(log->last_frame_id) +
                     ") are not in a checkpoint, and a mesh would leave them out; fold them in "
                     "first: depthfuse inspect --fold-log " + args.positional()[0]);
  const auto t0 = std::chrono::steady_clock::now();
  mesh::MeshReport report;
  std::vector<std::string> damaged;
  auto m = mesh::mesh_scan(**opened, filters, options, &report, &damaged);
  for (const std::string& d : damaged) DF_LOG(Export, Warning) << "skipped: " << d;
  if (!m) return cli::fail(m.status().message());
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  auto line = cli::write_mesh(out, *m, report, seconds);
  if (!line) return cli::fail(line.status().message());
  std::fputs(line->c_str(), stdout);
  if (!damaged.empty()) {
    DF_LOG(Export, Error) << damaged.size() << " damaged chunks were left out";
    return 1;
  }
  return 0;
}

int run(int argc, char** argv) {
  cli::Args args(argc, argv, {"no-color", "no-stats", "skip-damaged", "mesh", "help"});
  if (args.has("help")) return std::printf("usage: %s\n", kUsage), 0;
  if (!args.ok()) return cli::fail(args.error());
  std::vector<std::string> known = {"output", "min-merges", "bbox", "no-color", "no-stats",
                                    "trajectory", "skip-damaged", "mesh"};
  if (args.has("mesh")) known.insert(known.end(), cli::mesh_option_names().begin(), cli::mesh_option_names().end());
  const std::string bad = args.unknown(known);
  if (!bad.empty())
    return cli::fail("unknown option " + bad + (bad.rfind("--mesh-", 0) == 0 ? " (without --mesh)" : "") +
                     "\nusage: " + kUsage);
  if (args.positional().size() != 1 || !args.has("output"))
    return cli::fail(std::string("expected one scan file and -o out.ply|out.pcd\nusage: ") + kUsage);

  store::ExportOptions options;
  long min_merges = 0;
  std::string err;
  if (!args.get_int("min-merges", &min_merges, &err, daemon::closed(0, 65535))) return cli::fail(err);
  options.min_merges = static_cast<uint32_t>(min_merges);
  if (args.has("bbox")) {
    Eigen::AlignedBox3f box;
    if (!parse_bbox(args.get("bbox"), &box, &err)) return cli::fail(err);
    options.bbox_m = box;
  }
  options.with_color = !args.has("no-color");
  options.with_fusion_stats = !args.has("no-stats");
  options.skip_damaged = args.has("skip-damaged");
  const std::string out = args.get("output");
  if (args.has("mesh")) return export_mesh(args, options, out);
  if (auto format = store::cloud_format_for(out); !format) return cli::fail(format.status().message());

  auto opened = store::ScanStore::open(args.positional()[0], store::OpenMode::kReadOnly);
  if (!opened) return cli::fail(opened.status().message());
  store::ScanStore& scan = **opened;
  store::ScopedRead snapshot(scan);
  if (!snapshot.status()) return cli::fail(snapshot.status().message());
  // Frames after the last checkpoint that the redo log holds (killed, not resumed): replayed here
  // as a resume would, so that the export loses none of them.
  auto log = scan.frame_log_summary();
  if (!log) return cli::fail(log.status().message());
  std::optional<store::LogReplay> folded;
  if (log->count > 0) {
    const std::string how = " (resuming the scan, or depthfuse inspect --fold-log " + scan.path() +
                            ", folds them into the file)";
    auto config = cli::stored_reconstruction_config(scan);
    if (!config) return cli::fail(config.status().message() + how);
    auto replay = store::replay_frame_log(scan, *config);
    if (!replay) return cli::fail("folding the frame redo log of " + scan.path() + ": " +
                                  replay.status().message() + how);
    if (!replay->damaged) DF_LOG(Export, Warning) << replay->damaged.message() << ": the frame log is folded in up to the record before it";
    DF_LOG(Export, Info) << "folded in " << replay->poses.size() << " frames of the frame redo log ("
                         << log->first_frame_id << "-" << log->last_frame_id << ") after the last checkpoint";
    folded = std::move(replay).value();
    options.replacing = folded->map.get();
  }
  // The trajectory first: a damaged pose (its checksum fails) stops the export before the cloud
  // is written.
  if (args.has("trajectory")) {
    const Status st = store::export_trajectory(scan, args.get("trajectory"),
                                               folded ? folded->poses : std::vector<store::PoseRecord>{});
    if (!st) return cli::fail(st.message() + " (nothing exported)");
  }
  auto report = store::export_cloud(scan, out, options);
  if (!report) {
    if (args.has("trajectory")) std::remove(args.get("trajectory").c_str());
    return cli::fail(report.status().message());
  }
  for (const std::string& d : report->damaged) DF_LOG(Export, Warning) << "skipped: " << d;
  std::printf("wrote %llu points from %zu chunks to %s", static_cast<unsigned long long>(report->points_written),
              report->chunks_read, out.c_str());
  if (folded) std::printf(" (%zu logged frames folded in)", folded->poses.size());
  if (report->points_filtered) std::printf(" (%llu filtered out)", static_cast<unsigned long long>(report->points_filtered));
  std::printf("\n");
  if (!report->damaged.empty()) {
    DF_LOG(Export, Error) << report->damaged.size() << " damaged chunks were left out";
    return 1;
  }
  return 0;
}

}  // namespace

DF_REGISTER_COMMAND(export_cmd, kCmd, kUsage,
                    "write a scan file's cloud to PLY or PCD (streaming, works during a scan)", run);
