// depthfuse refine: the paper's batch loop over a scan file's keyframes (re-register each one
// against the whole cloud, fuse again, repeat), written back as a new checkpoint.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <memory>
#include <optional>

#include "cli_util.hpp"
#include "command.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/app_config.hpp"
#include "depthfuse/pipeline.hpp"
#include "depthfuse/store/scan_store.hpp"

using namespace depthfuse;

DF_LOG_CATEGORY(Refine)

namespace {

constexpr const char* kCmd = "refine";
constexpr const char* kUsage =
    "depthfuse refine <scan.db> [--iterations N] [--out refined.db] [--config FILE]\n"
    "         [--keyframe-stride N] [--max-keyframes N]\n"
    "  --iterations N       outer iterations of re-registration + fusion (default: the config's)\n"
    "  --out FILE           write a refined copy instead of a new checkpoint in <scan.db>\n"
    "  --config FILE        reconstruction settings (default: the configuration stored in the scan)\n"
    "  --keyframe-stride N  use every N-th keyframe (all keyframes are held in memory)";

struct Options {
  std::string scan;
  std::optional<std::string> out;  // a refined copy instead of a new checkpoint in the scan
  long iterations = -1;            // -1: the config's
  size_t keyframe_stride = 1;
  size_t max_keyframes = 0;        // 0: all
};

Result<Options> parse_options(const cli::Args& args) {
  if (args.positional().size() != 1) return invalid_argument("expected one scan file");
  Options o;
  o.scan = args.positional()[0];
  if (args.has("out")) o.out = args.get("out");
  long stride = 1, max_keyframes = 0;
  std::string err;
  if (!args.get_int("iterations", &o.iterations, &err, daemon::closed(0, cli::kMaxIterations)) ||
      !args.get_int("keyframe-stride", &stride, &err, daemon::closed(1, INT32_MAX)) ||
      !args.get_int("max-keyframes", &max_keyframes, &err, daemon::closed(0, INT32_MAX)))
    return invalid_argument(err);
  o.keyframe_stride = static_cast<size_t>(stride);
  o.max_keyframes = static_cast<size_t>(max_keyframes);
  return o;
}

// The scan file to refine, open for writing: the scan itself, or with --out a consistent copy of
// its last checkpoint (made while a writer may be active).
Result<std::unique_ptr<store::ScanStore>> open_scan(const Options& o) {
  std::string path = o.scan;
  if (o.out) {
    auto src = store::ScanStore::open(path, store::OpenMode::kReadOnly);
    if (!src) return src.status();
    DF_RETURN_IF_ERROR((*src)->copy_to(*o.out));
    path = *o.out;
  }
  return store::ScanStore::open(path, store::OpenMode::kReadWrite);
}

// The reconstruction settings: --config's, else those stored in the scan, else the defaults.
Result<ReconstructionConfig> scan_config(store::ScanStore& scan, const daemon::Startup& startup) {
  if (startup.args().has("config")) return startup.config().reconstruction;
  auto text = scan.config_toml();
  if (!text) return text.status();
  if (!*text) {
    DF_LOG(Refine, Info) << "the scan stores no configuration; using the defaults";
    return ReconstructionConfig{};
  }
  auto c = parse_app_config(**text, scan.path() + " (stored configuration)");
  if (!c) return c.status().with_context("the stored configuration does not load (give --config)");
  return c->reconstruction;
}

// The keyframes refined, all held in memory (refused up front when they would not fit).
struct Keyframes {
  std::vector<Frame> frames;
  std::vector<Pose> poses;
  std::vector<uint32_t> ids;
};

Result<Keyframes> read_keyframes(store::ScanStore& scan, const Options& o, cli::Progress& progress) {
  auto infos = scan.list_keyframes();
  if (!infos) return infos.status();
  if (infos->empty()) return not_found(scan.path() + ": the scan has no keyframes to refine");
  Keyframes k;
  size_t taken = (infos->size() + o.keyframe_stride - 1) / o.keyframe_stride;
  if (o.max_keyframes) taken = std::min(taken, o.max_keyframes);
  for (size_t i = 0; i < infos->size(); i += o.keyframe_stride) {
    if (o.max_keyframes && k.frames.size() >= o.max_keyframes) break;
    auto kf = scan.read_keyframe((*infos)[i].frame_id);
    if (!kf) return kf.status();
    k.frames.push_back(kf->to_frame());
    if (k.frames.size() == 1)
      DF_RETURN_IF_ERROR(cli::check_frames_fit(taken, cli::frame_bytes(k.frames[0]),
                                               "refining (the batch pipeline's rounds)",
                                               "take fewer with --max-keyframes or --keyframe-stride")
                             .with_context(scan.path()));
    k.poses.push_back(kf->T_world_cam);
    k.ids.push_back(kf->frame_id);
    progress("reading keyframes", i + 1, infos->size());
  }
  return k;
}

// The refined cloud replaces the old one and the keyframes' poses are updated, in one
// transaction; rolled back on any failure.
Status write_refined(store::ScanStore& scan, const Keyframes& k, const BatchResult& result,
                     const ReconstructionConfig& config, const store::ScanMetadata& meta) {
  // With a pose graph, the keyframes' poses refined from are the corrected ones, and the refined
  // cloud is in the graph's current version: a resume's deformation must not move it again.
  auto graph = scan.graph_summary();
  if (!graph) return graph.status();
  const uint32_t version = *graph ? (*graph)->deformation_version : 0;
  Status st = scan.begin_checkpoint();
  if (st) st = scan.delete_all_chunks();
  if (st) {
    result.map->for_each_chunk([&](const ChunkKey& key, Chunk& c) {
      c.version = version;
      if (st) st = scan.write_chunk(key, c);
    });
  }
  auto existing = scan.read_poses();
  if (st && !existing) st = existing.status();
  for (size_t i = 0; st && i < k.ids.size(); ++i) {
    st = scan.update_keyframe_pose(k.ids[i], result.T_world_cam[i]);
    store::PoseRecord p;
    p.frame_id = k.ids[i];
    p.utime = k.frames[i].utime;
    for (const auto& e : *existing)
      if (e.frame_id == k.ids[i]) p = e;
    p.T_world_cam = result.T_world_cam[i];
    if (st) st = scan.write_pose(p);
  }
  if (st) {
    store::ScanMetadata m = meta;
    m.chunk_size_m = config.fusion.chunk_size_m;
    m.method = to_string(Method::kFull);
    st = scan.set_metadata(m);
  }
  if (!st) scan.rollback_checkpoint();
  return st;
}

// Commits the refined checkpoint, as the last one was but for its reason, and compacts the file.
Result<store::CheckpointRecord> commit_refined(store::ScanStore& scan,
                                               const store::CheckpointRecord& last,
                                               const store::ScanMetadata& meta) {
  store::CheckpointInfo info;
  info.reason = "refine";
  info.last_frame_id = last.last_frame_id;
  info.T_world_cam = last.T_world_cam;
  info.frames_received = meta.frames_received;
  info.frames_fused = meta.frames_fused;
  info.frames_tracked_only = meta.frames_tracked_only;
  info.frames_lost = meta.frames_lost;
  info.frames_dropped = meta.frames_dropped;
  auto rec = scan.commit_checkpoint(info);
  if (!rec) return rec.status();
  if (auto st = scan.compact(); !st) {  // the old cloud's pages; failing here loses nothing
    DF_LOG(Refine, Warning) << st.message();
  }
  return rec;
}

// Refines the scan's keyframes and writes them back; the checkpoint it made, or what failed.
Result<store::CheckpointRecord> refine(store::ScanStore& scan, const ReconstructionConfig& config,
                                       const Options& o, size_t* keyframes, BatchResult* result) {
  auto last = scan.last_checkpoint();
  if (!last) return last.status();
  if (!*last) return not_found(scan.path() + ": no checkpoint to refine");
  auto meta = scan.metadata();
  if (!meta) return meta.status();
  cli::Progress progress;
  auto k = read_keyframes(scan, o, progress);
  if (!k) return k.status();
  *keyframes = k->frames.size();
  auto batch = reconstruct_batch(k->frames, k->poses, config, progress.fn());
  if (!batch) return batch.status();
  *result = std::move(*batch);
  if (const Status st = write_refined(scan, *k, *result, config, *meta); !st)
    return Status(st.code(), st.message() + " (the scan is unchanged)");
  auto rec = commit_refined(scan, **last, *meta);
  if (!rec) return Status(rec.status().code(), rec.status().message() + " (the scan is unchanged)");
  return rec;
}

int run(int argc, char** argv) {
  daemon::Startup startup(
      cli::offline_program(kCmd, kUsage, {"iterations", "out", "keyframe-stride", "max-keyframes"},
                           {}, 1, true),
      argc, argv);
  if (auto code = startup.exit_code()) return *code;
  const auto o = parse_options(startup.args());
  if (!o) return startup.usage_error(o.status().message());
  auto opened = open_scan(*o);
  if (!opened) return cli::fail(opened.status().message());
  store::ScanStore& scan = **opened;
  auto rc = scan_config(scan, startup);
  if (!rc) return cli::fail(rc.status().message());
  ReconstructionConfig config = rc->with_method(Method::kFull);
  if (o->iterations >= 0) config.pipeline.outer_iterations = static_cast<int>(o->iterations);

  const auto t0 = std::chrono::steady_clock::now();
  size_t keyframes = 0;
  BatchResult result;
  auto rec = refine(scan, config, *o, &keyframes, &result);
  if (!rec) return cli::fail(rec.status().message());
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("depthfuse refine\n  scan:        %s\n  keyframes:   %zu\n  iterations:\n",
              scan.path().c_str(), keyframes);
  for (const auto& it : result.iterations)
    std::fputs(cli::describe_iteration(it, keyframes).c_str(), stdout);
  if (result.converged_early) std::printf("  stopped early: the poses stopped moving\n");
  std::printf("  checkpoint:  #%lld, %llu points in %llu chunks\n  time:        %.1f s\n",
              static_cast<long long>(rec->id), static_cast<unsigned long long>(rec->point_count),
              static_cast<unsigned long long>(rec->chunk_count), seconds);
  return 0;
}

}  // namespace

DF_REGISTER_COMMAND(refine, kCmd, kUsage,
                    "re-register and re-fuse a scan file's keyframes (the paper's batch loop)", run);
