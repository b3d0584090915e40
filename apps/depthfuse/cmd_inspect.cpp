// depthfuse inspect: what a scan file holds, and whether it is intact.
#include <cinttypes>
#include <cstdio>
#include <ctime>

#include "cli_util.hpp"
#include "command.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/store/scan_store.hpp"
#include "frame_log_fold.hpp"

using namespace depthfuse;

DF_LOG_CATEGORY(Inspect)

namespace {

constexpr const char* kCmd = "inspect";
constexpr const char* kUsage =
    "depthfuse inspect <scan.db> [--quick] [--checkpoints] [--chunks] [--upgrade] [--fold-log]\n"
    "  --quick        SQLite's integrity check only, blobs are not decoded\n"
    "  --checkpoints  list every checkpoint\n"
    "  --chunks       list every chunk (key, points, bounds)\n"
    "  --upgrade      migrate an older schema in place (opens the file for writing)\n"
    "  --fold-log     replay the frame redo log of a scan killed mid-scan into a new checkpoint\n"
    "                 (opens the file for writing, as resuming the scan would)";

std::string format_time(int64_t utime) {
  if (utime <= 0) return "-";
  const std::time_t t = static_cast<std::time_t>(utime / 1000000);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[64];
  std::strftime(buf, sizeof(buf), "%Y-%m-%d %H:%M:%S UTC", &tm);
  return buf;
}

std::string mib(uint64_t bytes) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.1f MiB", bytes / (1024.0 * 1024.0));
  return buf;
}

// --upgrade and --fold-log: the changes to the file asked for, before it is read.
Status change_file(const std::string& path, const cli::Args& args) {
  if (args.has("upgrade")) {
    auto rw = store::ScanStore::open(path, store::OpenMode::kReadWrite);
    if (!rw) return rw.status();
    const auto& rep = (*rw)->open_report();
    std::printf("%s: schema %d%s\n", path.c_str(), rep.found_schema_version,
                rep.migrated ? (" migrated to " + std::to_string(store::kSchemaVersion)).c_str()
                             : " is current");
  }
  if (args.has("fold-log")) {
    auto folded = cli::fold_frame_log(path);
    if (!folded) return folded.status();
    std::printf("%s: %zu logged frames folded into a new checkpoint\n", path.c_str(), *folded);
  }
  return Status::ok();
}

void print_summary(const store::StoreSummary& s) {
  std::printf("scan file      %s\n", s.path.c_str());
  std::printf("schema version %d\n", s.schema_version);
  std::printf("scan id        %s\n", s.metadata.scan_id.empty() ? "-" : s.metadata.scan_id.c_str());
  std::printf("created        %s\n", format_time(s.metadata.created_utime).c_str());
  std::printf("sensor         %s\n", s.metadata.sensor_serial.empty() ? "-" : s.metadata.sensor_serial.c_str());
  std::printf("method         %s\n", s.metadata.method.empty() ? "-" : s.metadata.method.c_str());
  std::printf("configuration  %s\n", s.has_config ? "stored" : "none");
  std::printf("frames         %" PRIu64 " received, %" PRIu64 " fused, %" PRIu64
              " tracked only (fusion behind), %" PRIu64 " lost, %" PRIu64
              " dropped; %zu poses, %zu keyframes (%s)\n",
              s.metadata.frames_received, s.metadata.frames_fused, s.metadata.frames_tracked_only,
              s.metadata.frames_lost, s.metadata.frames_dropped, s.pose_count, s.keyframe_count,
              mib(s.keyframe_bytes).c_str());
  std::printf("points         %" PRIu64 " in %zu chunks of %.3g m (%s)\n", s.point_count, s.chunk_count,
              s.metadata.chunk_size_m, mib(s.chunk_bytes).c_str());
  if (s.extent_m.isEmpty()) {
    std::printf("extent         -\n");
  } else {
    const Eigen::Vector3f size = s.extent_m.sizes();
    std::printf("extent         [%.3f, %.3f, %.3f] .. [%.3f, %.3f, %.3f] m (%.2f x %.2f x %.2f m)\n",
                s.extent_m.min().x(), s.extent_m.min().y(), s.extent_m.min().z(), s.extent_m.max().x(),
                s.extent_m.max().y(), s.extent_m.max().z(), size.x(), size.y(), size.z());
  }
  if (s.last_checkpoint) {
    std::printf("checkpoints    %zu, last #%" PRId64 " at %s (%s, frame %u)\n", s.checkpoint_count,
                s.last_checkpoint->id, format_time(s.last_checkpoint->utime).c_str(),
                s.last_checkpoint->reason.c_str(), s.last_checkpoint->last_frame_id);
  } else {
    std::printf("checkpoints    none\n");
  }
  if (s.graph) {
    const store::GraphSummary& g = *s.graph;
    std::printf(
        "pose graph     %zu keyframes (%s), %zu loops, version %u; deformation history from "
        "version %u (written by checkpoint #%" PRId64 ")\n",
        g.keyframes, mib(g.keyframe_bytes + g.state_bytes).c_str(), g.loops, g.version,
        g.deformation_oldest_version, g.checkpoint_id);
  } else if (!s.graph_problem.empty()) {
    std::printf("pose graph     unreadable: %s\n", s.graph_problem.c_str());
  } else {
    std::printf("pose graph     none\n");
  }
  if (s.pending_rows)
    std::printf("pending        %" PRIu64 " points moved by a loop closure into %zu chunk versions "
                "not yet brought up to date (a resume or export places them)\n",
                s.pending_points, s.pending_rows);
  if (s.staged_chunk_count)
    std::printf("staged         %zu evicted chunks not yet in a checkpoint (a writer is active or crashed)\n",
                s.staged_chunk_count);
}

// The frame redo log after the last checkpoint: frames a resume (or export) replays.
void print_frame_log(store::ScanStore& scan) {
  if (auto log = scan.frame_log_summary(); !log) {
    DF_LOG(Inspect, Error) << log.status().message();
  } else if (log->count == 0) {
    std::printf("frame log      empty\n");
  } else {
    std::printf("frame log      %zu frames (%u-%u) after the last checkpoint, %s: a resume or export "
                "replays them\n",
                log->count, log->first_frame_id, log->last_frame_id, mib(log->bytes).c_str());
  }
}

// --checkpoints and --chunks.
Status print_lists(store::ScanStore& scan, const cli::Args& args) {
  if (args.has("checkpoints")) {
    auto cps = scan.checkpoints();
    if (!cps) return cps.status();
    for (const auto& c : *cps)
      std::printf("  checkpoint #%" PRId64 "  %s  %-8s frame %u  %" PRIu64 " points  %" PRIu64 " chunks\n", c.id,
                  format_time(c.utime).c_str(), c.reason.c_str(), c.last_frame_id, c.point_count, c.chunk_count);
  }
  if (args.has("chunks")) {
    auto chunks = scan.list_chunks(true);
    if (!chunks) return chunks.status();
    for (const auto& c : *chunks)
      std::printf("  chunk %-16s %7u points  %8zu bytes  %s\n", store::to_string(c.key).c_str(), c.point_count,
                  c.blob_bytes, c.checkpoint_id ? ("checkpoint " + std::to_string(c.checkpoint_id)).c_str() : "staged");
  }
  return Status::ok();
}

// What a full check covered: only what was checked is said (poses written before schema 3 have
// no checksum).
std::string describe_checked(const store::IntegrityReport& integrity) {
  const size_t poses_summed = integrity.poses_checked - integrity.poses_unchecked;
  std::string checked = "; " + std::to_string(integrity.chunks_checked) + " chunk, " +
                        std::to_string(integrity.keyframes_checked) + " keyframe and " +
                        std::to_string(integrity.graph_keyframes_checked) +
                        " pose graph keyframe records decoded and checksummed; " +
                        std::to_string(poses_summed) + " pose records checksummed";
  if (integrity.poses_unchecked > 0)
    checked += ", " + std::to_string(integrity.poses_unchecked) +
               " unchecked (written before schema 3, without a checksum: only decoded)";
  for (auto [n, what] : {std::pair{integrity.keyframes_unchecked, " keyframe"},
                         std::pair{integrity.checkpoints_unchecked, " checkpoint"}})
    if (n > 0)
      checked += "; " + std::to_string(n) + what +
                 " poses unchecked (written before schema 4, without a checksum: only decoded)";
  if (integrity.chunks_unchecked > 0)
    checked += "; " + std::to_string(integrity.chunks_unchecked) +
               " chunk rows unchecked (written before schema 6, without a checksum: blobs checked)";
  checked += "; " + std::to_string(integrity.log_records_checked) +
             " frame log records decoded and checksummed";
  return checked;
}

// The integrity line; the exit code: 0 intact, 1 damaged.
int check_integrity(store::ScanStore& scan, bool quick) {
  auto integrity = scan.integrity_check(!quick);
  if (!integrity) return cli::fail(integrity.status().message());
  if (integrity->ok()) {
    const std::string checked = quick ? "; blobs not checked (--quick)" : describe_checked(*integrity);
    std::printf("integrity      ok (sqlite integrity_check%s)\n", checked.c_str());
    return 0;
  }
  std::printf("integrity      DAMAGED: %zu problems\n", integrity->problems.size());
  for (const auto& p : integrity->problems) DF_LOG(Inspect, Error) << p;
  return 1;
}

int run(int argc, char** argv) {
  daemon::Startup startup(cli::offline_program(kCmd, kUsage, {},
                                               {"quick", "checkpoints", "chunks", "upgrade", "fold-log"},
                                               1, false),
                          argc, argv);
  if (auto code = startup.exit_code()) return *code;
  const cli::Args& args = startup.args();
  if (args.positional().size() != 1) return startup.usage_error("expected one scan file");
  const std::string path = args.positional()[0];
  if (const Status changed = change_file(path, args); !changed) return cli::fail(changed.message());
  auto opened = store::ScanStore::open(path, store::OpenMode::kReadOnly);
  if (!opened) return cli::fail(opened.status().message());
  store::ScanStore& scan = **opened;

  auto sum = scan.summary();
  if (!sum) {
    // Damaged beyond a summary: still say what the integrity check finds.
    DF_LOG(Inspect, Error) << sum.status().message();
    auto integrity = scan.integrity_check(!args.has("quick"));
    if (integrity) {
      for (const auto& p : integrity->problems) DF_LOG(Inspect, Error) << p;
    }
    std::printf("integrity      DAMAGED\n");
    return 1;
  }
  print_summary(*sum);
  print_frame_log(scan);
  std::printf("file size      %s (+ %s WAL)\n", mib(sum->file_bytes).c_str(), mib(sum->wal_bytes).c_str());
  if (const Status listed = print_lists(scan, args); !listed) return cli::fail(listed.message());
  return check_integrity(scan, args.has("quick"));
}

}  // namespace

DF_REGISTER_COMMAND(inspect, kCmd, kUsage,
                    "summarise a scan file and check its integrity", run);
