// depthfuse refine: the paper's batch loop over a scan file's keyframes (re-register each one
// against the whole cloud, fuse again, repeat), written back as a new checkpoint.
#include <algorithm>
#include <chrono>
#include <cstdio>

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

Result<ReconstructionConfig> scan_config(store::ScanStore& scan, const cli::Args& args) {
  if (args.has("config")) {
    auto c = load_app_config(args.get("config"));
    if (!c) return c.status();
    return c->reconstruction;
  }
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

int run(int argc, char** argv) {
  cli::Args args(argc, argv, {"help"});
  if (args.has("help")) return std::printf("usage: %s\n", kUsage), 0;
  if (!args.ok()) return cli::fail(args.error());
  const std::string bad = args.unknown({"iterations", "out", "config", "keyframe-stride", "max-keyframes"});
  if (!bad.empty()) return cli::fail("unknown option " + bad + "\nusage: " + kUsage);
  if (args.positional().size() != 1) return cli::fail(std::string("expected one scan file\nusage: ") + kUsage);
  long iterations = -1, stride = 1, max_keyframes = 0;
  std::string err;
  if (!args.get_int("iterations", &iterations, &err, daemon::closed(0, cli::kMaxIterations)) ||
      !args.get_int("keyframe-stride", &stride, &err, daemon::closed(1, INT32_MAX)) ||
      !args.get_int("max-keyframes", &max_keyframes, &err, daemon::closed(0, INT32_MAX)))
    return cli::fail(err);

  std::string path = args.positional()[0];
  if (args.has("out")) {
    // A consistent copy of the last checkpoint (works while a writer is active), refined there.
    auto src = store::ScanStore::open(path, store::OpenMode::kReadOnly);
    if (!src) return cli::fail(src.status().message());
    if (auto st = (*src)->copy_to(args.get("out")); !st) return cli::fail(st.message());
    path = args.get("out");
  }
  auto opened = store::ScanStore::open(path, store::OpenMode::kReadWrite);
  if (!opened) return cli::fail(opened.status().message());
  store::ScanStore& scan = **opened;

  auto rc = scan_config(scan, args);
  if (!rc) return cli::fail(rc.status().message());
  ReconstructionConfig config = rc->with_method(Method::kFull);
  if (iterations >= 0) config.pipeline.outer_iterations = static_cast<int>(iterations);

  auto last = scan.last_checkpoint();
  if (!last) return cli::fail(last.status().message());
  if (!*last) return cli::fail(path + ": no checkpoint to refine");
  auto meta = scan.metadata();
  if (!meta) return cli::fail(meta.status().message());
  auto infos = scan.list_keyframes();
  if (!infos) return cli::fail(infos.status().message());
  if (infos->empty()) return cli::fail(path + ": the scan has no keyframes to refine");

  const auto t0 = std::chrono::steady_clock::now();
  cli::Progress progress;
  std::vector<Frame> frames;
  std::vector<Pose> poses;
  std::vector<uint32_t> ids;
  size_t taken = (infos->size() + static_cast<size_t>(stride) - 1) / static_cast<size_t>(stride);
  if (max_keyframes) taken = std::min(taken, static_cast<size_t>(max_keyframes));
  for (size_t i = 0; i < infos->size(); i += static_cast<size_t>(stride)) {
    if (max_keyframes && frames.size() >= static_cast<size_t>(max_keyframes)) break;
    auto k = scan.read_keyframe((*infos)[i].frame_id);
    if (!k) return cli::fail(k.status().message());
    frames.push_back(k->to_frame());
    if (frames.size() == 1) {
      const Status fits = cli::check_frames_fit(taken, cli::frame_bytes(frames[0]),
                                                "refining (the batch pipeline's rounds)",
                                                "take fewer with --max-keyframes or --keyframe-stride");
      if (!fits) return cli::fail(path + ": " + fits.message());
    }
    poses.push_back(k->T_world_cam);
    ids.push_back(k->frame_id);
    progress("reading keyframes", i + 1, infos->size());
  }

  auto result = reconstruct_batch(frames, poses, config, progress.fn());
  if (!result) return cli::fail(result.status().message());

  // One transaction: the refined cloud replaces the old one, keyframe poses are updated.
  Status st = scan.begin_checkpoint();
  if (st) st = scan.delete_all_chunks();
  if (st) {
    result->map->for_each_chunk([&](const ChunkKey& key, const Chunk& c) {
      if (st) st = scan.write_chunk(key, c);
    });
  }
  auto existing = scan.read_poses();
  if (st && !existing) st = existing.status();
  for (size_t i = 0; st && i < ids.size(); ++i) {
    st = scan.update_keyframe_pose(ids[i], result->T_world_cam[i]);
    store::PoseRecord p;
    p.frame_id = ids[i];
    p.utime = frames[i].utime;
    for (const auto& e : *existing)
      if (e.frame_id == ids[i]) p = e;
    p.T_world_cam = result->T_world_cam[i];
    if (st) st = scan.write_pose(p);
  }
  if (st) {
    store::ScanMetadata m = *meta;
    m.chunk_size_m = config.fusion.chunk_size_m;
    m.method = to_string(Method::kFull);
    st = scan.set_metadata(m);
  }
  if (!st) {
    scan.rollback_checkpoint();
    return cli::fail(st.message() + " (the scan is unchanged)");
  }
  store::CheckpointInfo info;
  info.reason = "refine";
  info.last_frame_id = (*last)->last_frame_id;
  info.T_world_cam = (*last)->T_world_cam;
  info.frames_received = meta->frames_received;
  info.frames_fused = meta->frames_fused;
  info.frames_dropped = meta->frames_dropped;
  auto rec = scan.commit_checkpoint(info);
  if (!rec) return cli::fail(rec.status().message() + " (the scan is unchanged)");
  if (auto st = scan.compact(); !st) {  // the old cloud's pages; failing here loses nothing
    DF_LOG(Refine, Warning) << st.message();
  }

  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("depthfuse refine\n  scan:        %s\n  keyframes:   %zu\n  iterations:\n", path.c_str(), frames.size());
  for (const auto& it : result->iterations)
    std::fputs(cli::describe_iteration(it, frames.size()).c_str(), stdout);
  if (result->converged_early) std::printf("  stopped early: the poses stopped moving\n");
  std::printf("  checkpoint:  #%lld, %llu points in %llu chunks\n  time:        %.1f s\n",
              static_cast<long long>(rec->id), static_cast<unsigned long long>(rec->point_count),
              static_cast<unsigned long long>(rec->chunk_count), seconds);
  return 0;
}

}  // namespace

DF_REGISTER_COMMAND(refine, kCmd, kUsage,
                    "re-register and re-fuse a scan file's keyframes (the paper's batch loop)", run);
