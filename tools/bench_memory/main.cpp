// bench_memory: resident memory (VmRSS from /proc/self/status) over a long synthetic scan, with
// the MapPager bounding the fused map versus an unbounded map, each in its own process; then
// whether the two runs produced the same cloud and the same poses, and their pose error against
// the ground truth.
//
// The scan is the synthetic driver's rooms walk (16 rooms of 5 x 5 m, walked around ~8 times in
// 20 minutes), rendered at Kinect V2 geometry with noise, fused by the incremental pipeline
// (pre-filter, re-registration, fusion) and recorded by ScanRecorder exactly as the fusion daemon
// does: pose per frame, a keyframe every n frames, a checkpoint every interval, post-filter and a
// final checkpoint at the end.
//
//   bench_memory --minutes 20 --rate-hz 30 --budget-mib 256          (the figure; long)
//   bench_memory --minutes 3 --rate-hz 10 --budget-mib 64            (a quick look)
#include <malloc.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "depthfuse/base/log.hpp"
#include "depthfuse/pipeline.hpp"
#include "depthfuse/store/map_pager.hpp"
#include "depthfuse/store/scan_recorder.hpp"
#include "depthfuse/store/scan_store.hpp"
#include "depthfuse/synthetic/synthetic_sequence.hpp"

using namespace depthfuse;
using Clock = std::chrono::steady_clock;

DF_LOG_CATEGORY(BenchMemory)

namespace {

struct Options {
  double minutes = 20.0;
  double rate_hz = 30.0;
  double budget_mib = 256.0;
  double evict_distance_m = 1.5;
  double min_age_s = 1.0;                // chunks seen this recently stay resident
  double checkpoint_interval_s = 30.0;   // of scan time
  int keyframe_every = 10;
  double report_every_s = 30.0;          // of scan time
  std::string mode = "both";             // both | bounded | unbounded
  std::string dir = "bench-memory-out";
  uint64_t seed = 1;
  bool noise = true;
};

void usage() {
  std::printf(
      "usage: bench_memory [--minutes M] [--rate-hz R] [--budget-mib B] [--evict-distance-m D]\n"
      "                    [--min-age-s A]\n"
      "                    [--checkpoint-s S] [--keyframe-every N] [--report-s S]\n"
      "                    [--mode both|bounded|unbounded|compare] [--dir DIR] [--seed N] [--no-noise]\n"
      "  Scan length is M minutes of frames at R Hz (the walk is 0.5 m/s whatever R is).\n"
      "  DIR receives bounded.db and unbounded.db (deleted first). --mode compare only compares\n"
      "  the two files already in DIR (e.g. a bounded run of another budget against the\n"
      "  unbounded.db of an earlier run with the same scan options, linked into DIR).\n"
      "  Columns: other_MiB = VmRSS - map_MiB, what the process holds besides the map's point data\n"
      "  (scene, pipeline scratch, SQLite cache, allocator slack): the overhead that must not grow.\n"
      "  map_MiB counts vector capacity as the budget does; capacity never written is not resident,\n"
      "  so other_MiB understates (even below 0) while chunks are growing. heap_free_MiB: freed\n"
      "  memory malloc keeps in its heap (mallinfo2 fordblks); malloc_trim hands its whole pages\n"
      "  back to the OS, so only part of it is resident. VmHWM in the last line is the true peak\n"
      "  (also inside checkpoints); peak_MiB is the highest VmRSS sampled after each frame since\n"
      "  the previous line.\n");
}

bool parse(int argc, char** argv, Options* o) {
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&](double* v) {
      if (i + 1 >= argc) return false;
      char* end = nullptr;
      *v = std::strtod(argv[++i], &end);
      return *end == 0 && std::isfinite(*v);
    };
    double v = 0;
    if (a == "--minutes" && next(&v)) o->minutes = v;
    else if (a == "--rate-hz" && next(&v)) o->rate_hz = v;
    else if (a == "--budget-mib" && next(&v)) o->budget_mib = v;
    else if (a == "--evict-distance-m" && next(&v)) o->evict_distance_m = v;
    else if (a == "--min-age-s" && next(&v)) o->min_age_s = v;
    else if (a == "--checkpoint-s" && next(&v)) o->checkpoint_interval_s = v;
    else if (a == "--keyframe-every" && next(&v)) o->keyframe_every = static_cast<int>(v);
    else if (a == "--report-s" && next(&v)) o->report_every_s = v;
    else if (a == "--seed" && next(&v)) o->seed = static_cast<uint64_t>(v);
    else if (a == "--mode" && i + 1 < argc) o->mode = argv[++i];
    else if (a == "--dir" && i + 1 < argc) o->dir = argv[++i];
    else if (a == "--no-noise") o->noise = false;
    else return false;
  }
  return o->minutes > 0 && o->rate_hz > 0 && o->budget_mib > 0 &&
         (o->mode == "both" || o->mode == "bounded" || o->mode == "unbounded" || o->mode == "compare");
}

// A field of /proc/self/status in MiB (VmRSS, VmHWM).
double proc_status_mib(const char* field) {
  std::ifstream in("/proc/self/status");
  std::string line;
  const size_t n = std::strlen(field);
  while (std::getline(in, line)) {
    if (line.compare(0, n, field) == 0 && line.size() > n && line[n] == ':')
      return std::strtod(line.c_str() + n + 1, nullptr) / 1024.0;  // kB
  }
  return 0.0;
}

synthetic::SyntheticConfig scan_config(const Options& o) {
  synthetic::SyntheticConfig c;
  c.scene = synthetic::SceneKind::kRooms;
  c.rate_hz = o.rate_hz;
  c.frames = static_cast<int>(std::lround(o.minutes * 60.0 * o.rate_hz));
  c.seed = o.seed;
  if (!o.noise) c.noise = synthetic::NoiseConfig::none();
  return c;
}

// One run in this process. Returns the exit code.
int run(const Options& o, bool bounded) {
  const char* name = bounded ? "bounded" : "unbounded";
  auto seq = synthetic::SyntheticSequence::create(scan_config(o));
  if (!seq) {
    DF_LOG(BenchMemory, Error) << seq.status().to_string();
    return 1;
  }
  ReconstructionConfig config;
  config = config.with_method(Method::kFull);
  store::RecorderConfig rc;
  rc.bounded_memory = bounded;
  rc.pager.memory_budget_mib = o.budget_mib;
  rc.pager.evict_distance_m = o.evict_distance_m;
  rc.pager.min_age_frames = static_cast<int>(std::lround(o.min_age_s * o.rate_hz));
  rc.keyframe_every_n_frames = o.keyframe_every;
  store::ScanMetadata meta;
  meta.scan_id = std::string("bench-memory-") + name;
  meta.sensor_serial = "synthetic";
  meta.method = to_string(Method::kFull);
  meta.chunk_size_m = config.fusion.chunk_size_m;
  const std::string path = o.dir + "/" + name + ".db";
  auto made = store::ScanRecorder::create(path, meta, synthetic::synthetic_config_to_toml(seq->config()),
                                          "bench_memory", rc);
  if (!made) {
    DF_LOG(BenchMemory, Error) << made.status().to_string();
    return 1;
  }
  store::ScanRecorder& recorder = **made;
  IncrementalReconstructor rec(config);

  const double rss_start = proc_status_mib("VmRSS");
  std::printf("[%s] %zu frames (%.1f min at %.0f Hz), map budget %s (evict beyond %.2f m, unseen for %d "
              "frames); VmRSS at start %.1f MiB\n",
              name, seq->size(), o.minutes, o.rate_hz,
              bounded ? (std::to_string(static_cast<int>(o.budget_mib)) + " MiB").c_str() : "none",
              rc.pager.evict_distance_m, rc.pager.min_age_frames, rss_start);
  std::printf("[%s] %8s %7s %10s %8s %10s %10s %10s %9s %8s %7s %7s %13s %9s\n", name, "scan_s", "frame", "map_pts",
              "chunks", "map_MiB", "VmRSS_MiB", "other_MiB", "evicted", "loaded", "ckpts", "fps", "heap_free_MiB", "peak_MiB");
  const auto t0 = Clock::now();
  auto t_report = t0;
  size_t frames_at_report = 0;
  double next_checkpoint_s = o.checkpoint_interval_s, next_report_s = 0.0;
  double sq_error = 0.0, max_rss = 0.0, interval_max_rss = 0.0;
  size_t errors = 0;
  Frame frame;
  for (size_t i = 0; i < seq->size(); ++i) {
    seq->render_into(i, o.noise, &frame);
    if (auto st = recorder.prepare_frame(frame, rec.initial_pose(frame, std::nullopt), rec); !st) {
      ++errors;
      if (errors < 5) {
        DF_LOG(BenchMemory, Error) << "[" << name << "] " << st.to_string();
      }
    }
    auto report = rec.process(frame);
    if (!report) {
      DF_LOG(BenchMemory, Error) << "[" << name << "] frame " << i << ": " << report.status().to_string();
      return 1;
    }
    const double e = (report->T_world_cam.translation() - seq->T_world_cam_true(i).translation()).norm();
    sq_error += e * e;
    if (auto st = recorder.record_frame(frame, *report, &rec.map()); !st) {
      ++errors;
      if (errors < 5) {
        DF_LOG(BenchMemory, Error) << "[" << name << "] " << st.to_string();
      }
    }
    const double scan_s = static_cast<double>(i + 1) / o.rate_hz;
    if (scan_s >= next_checkpoint_s) {
      next_checkpoint_s += o.checkpoint_interval_s;
      if (auto ck = recorder.checkpoint(&rec.map(), "periodic"); !ck) {
        DF_LOG(BenchMemory, Error) << "[" << name << "] checkpoint: " << ck.status().to_string();
      }
    }
    const double rss = proc_status_mib("VmRSS");
    max_rss = std::max(max_rss, rss);
    interval_max_rss = std::max(interval_max_rss, rss);
    if (scan_s >= next_report_s || i + 1 == seq->size()) {
      next_report_s += o.report_every_s;
      const auto now = Clock::now();
      const double dt = std::chrono::duration<double>(now - t_report).count();
      const double fps = dt > 0 ? static_cast<double>(i + 1 - frames_at_report) / dt : 0.0;
      t_report = now;
      frames_at_report = i + 1;
      size_t map_bytes = 0;
      rec.map().for_each_chunk([&](const ChunkKey&, const Chunk& c) { map_bytes += store::MapPager::chunk_bytes(c); });
      const store::RecorderStatus& s = recorder.status();
      std::printf("[%s] %8.1f %7zu %10zu %8zu %10.1f %10.1f %10.1f %9llu %8llu %7llu %7.1f %13.1f %9.1f\n", name, scan_s,
                  i + 1, rec.map().point_count(), rec.map().chunk_count(), map_bytes / 1048576.0, rss,
                  rss - map_bytes / 1048576.0,
                  static_cast<unsigned long long>(s.pager.total_evicted),
                  static_cast<unsigned long long>(s.pager.total_loaded),
                  static_cast<unsigned long long>(s.checkpoints_written), fps, mallinfo2().fordblks / 1048576.0,
                  interval_max_rss);
      interval_max_rss = 0.0;
      std::fflush(stdout);
    }
  }
  rec.finish();
  auto fin = recorder.finish(&rec.map());
  if (!fin) {
    DF_LOG(BenchMemory, Error) << "[" << name << "] final checkpoint: " << fin.status().to_string();
    return 1;
  }
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  const store::RecorderStatus& s = recorder.status();
  std::printf("[%s] done in %.0f s: %llu points in %llu chunks; peak VmRSS %.1f MiB (VmHWM %.1f MiB), "
              "start %.1f MiB; pose RMSE vs truth %.2f mm; evicted %llu, loaded %llu, unevictable now %.1f MiB, "
              "load collisions %llu, errors %zu; last checkpoint took %.2f s\n",
              name, seconds, static_cast<unsigned long long>(fin->point_count),
              static_cast<unsigned long long>(fin->chunk_count), max_rss, proc_status_mib("VmHWM"), rss_start,
              1000.0 * std::sqrt(sq_error / static_cast<double>(seq->size())),
              static_cast<unsigned long long>(s.pager.total_evicted),
              static_cast<unsigned long long>(s.pager.total_loaded), s.pager.unevictable_bytes / 1048576.0,
              static_cast<unsigned long long>(s.pager.load_collisions), errors, s.last_checkpoint_seconds);
  return 0;
}

// Streams both scan files in key order and compares chunk by chunk, then the poses.
int compare(const Options& o) {
  auto a = store::ScanStore::open(o.dir + "/unbounded.db", store::OpenMode::kReadOnly);
  auto b = store::ScanStore::open(o.dir + "/bounded.db", store::OpenMode::kReadOnly);
  if (!a || !b) {
    DF_LOG(BenchMemory, Error) << (!a ? a.status() : b.status()).to_string();
    return 1;
  }
  auto la = (*a)->list_chunks(), lb = (*b)->list_chunks();
  if (!la || !lb) return 1;
  size_t same = 0, different = 0, only_one = 0;
  uint64_t points = 0;
  size_t j = 0;
  for (const store::ChunkInfo& ca : *la) {
    points += ca.point_count;
    while (j < lb->size() && std::tie((*lb)[j].key.x, (*lb)[j].key.y, (*lb)[j].key.z) <
                                 std::tie(ca.key.x, ca.key.y, ca.key.z)) {
      ++only_one;
      ++j;
    }
    if (j >= lb->size() || (*lb)[j].key != ca.key) {
      ++only_one;
      continue;
    }
    auto pa = (*a)->read_chunk(ca.key), pb = (*b)->read_chunk(ca.key);
    if (pa && pb && pa->chunk.points() == pb->chunk.points()) ++same;
    else ++different;
    ++j;
  }
  only_one += lb->size() - j;
  auto poses_a = (*a)->read_poses(), poses_b = (*b)->read_poses();
  if (!poses_a || !poses_b) return 1;
  double max_dt = 0.0;
  size_t n = std::min(poses_a->size(), poses_b->size());
  for (size_t i = 0; i < n; ++i)
    max_dt = std::max(max_dt, ((*poses_a)[i].T_world_cam.translation() - (*poses_b)[i].T_world_cam.translation()).norm());
  std::printf("[compare] cloud: %zu chunks (%llu points) identical, %zu differ, %zu in one run only; "
              "poses: %zu vs %zu, max difference %.3g m\n",
              same, static_cast<unsigned long long>(points), different, only_one, poses_a->size(),
              poses_b->size(), max_dt);
  return (different == 0 && only_one == 0 && poses_a->size() == poses_b->size() && max_dt == 0.0) ? 0 : 3;
}

}  // namespace

int main(int argc, char** argv) {
  log::set_program_name("bench_memory");
  Options o;
  if (argc > 1 && (!std::strcmp(argv[1], "--help") || !std::strcmp(argv[1], "-h"))) {
    usage();
    return 0;
  }
  if (!parse(argc, argv, &o)) {
    usage();
    return 2;
  }
  if (o.mode == "compare") return compare(o);
  std::filesystem::create_directories(o.dir);
  for (const char* name : {"bounded", "unbounded"}) {
    if (o.mode != "both" && o.mode != name) continue;
    for (const char* suffix : {".db", ".db-wal", ".db-shm"})
      std::filesystem::remove(o.dir + "/" + name + suffix);
  }
  if (o.mode != "both") return run(o, o.mode == "bounded");
  // Each run in a process of its own, so that VmRSS is the run's alone.
  for (bool bounded : {false, true}) {
    std::fflush(stdout);
    const pid_t child = fork();
    if (child == 0) {
      const int code = run(o, bounded);
      std::fflush(stdout);  // _exit does not flush stdio
      _exit(code);
    }
    int status = 0;
    waitpid(child, &status, 0);
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
      DF_LOG(BenchMemory, Error) << "the " << (bounded ? "bounded" : "unbounded") << " run failed";
      return 1;
    }
  }
  return compare(o);
}
