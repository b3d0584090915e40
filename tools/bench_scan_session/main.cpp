// bench_scan_session: the fusion daemon's scan (ScanSession over the SQLite checkpoint sink, the
// per-frame path the daemon's worker runs: predict, page, register, fuse, record, pose graph,
// deformation, periodic checkpoints) over a long scan without LCM and without pacing, so that what
// the scan costs per frame and in memory as it grows shows without the capture's rendering sharing
// the cores. The source loops (reopened at its end) until --frames frames were processed.
// With --rate, frames come as from the capture daemon instead: a thread of their own reads them at
// that rate into a queue of --queue frames that drops the oldest when full, as the daemon's does,
// so that slow frames cost dropped frames (and the loop closer's thread the time it has live); as
// the daemon does, a frame taken while the queue fills is tracked only
// (fusion_daemon.shed_fusion_queue_share).
//
//   bench_scan_session --source 'synthetic:furnished?frames=6000&hints=0' --frames 6000
//   bench_scan_session --source tum:DIR --frames 4000 --config budget.toml
//   bench_scan_session --source 'synthetic:furnished?frames=36000&hints=0' --frames 36000 --rate 30
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <deque>
#include <fstream>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "depthfuse/app_config.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/source_factory.hpp"
#include "depthfuse/synthetic/synthetic_sequence.hpp"
#include "depthfuse/synthetic/synthetic_source.hpp"
#include "memory_budget.hpp"
#include "scan_session.hpp"
#include "sqlite_checkpoint_sink.hpp"

using namespace depthfuse;
using Clock = std::chrono::steady_clock;

DF_LOG_CATEGORY(BenchScanSession)

namespace {

struct Options {
  std::string source;
  std::string config_path;
  std::string dir;
  long frames = 6000;
  long report_every = 300;
  double slow_ms = 0;  // a line for every frame slower than this (0: none)
  double drift_mm = 0;  // a line for every frame further than this from the truth (0: none)
  // A line for every frame whose sequence is in [trace_from, trace_to] (trace_to 0: none).
  uint32_t trace_from = 0, trace_to = 0;
  bool traced(uint32_t sequence) const {
    return trace_to > 0 && sequence >= trace_from && sequence <= trace_to;
  }
  double rate_hz = 0;  // frames paced at this rate through a dropping queue (0: every frame, unpaced)
  size_t queue = 4;
};

void usage() {
  std::printf(
      "usage: bench_scan_session --source SPEC [--frames N] [--report-every N] [--config FILE]\n"
      "                          [--dir DIR] [--log-level SPEC] [--slow-ms MS] [--drift-mm MM]\n"
      "                          [--rate HZ [--queue N]] [--trace FROM:TO]\n"
      "  --source SPEC       a frame source as depthfuse-capture takes it (looped)\n"
      "  --frames N          frames to process in all (default 6000)\n"
      "  --report-every N    a line of figures every N frames (default 300)\n"
      "  --config FILE       the appliance's TOML (e.g. another fusion_daemon.memory_budget_mib)\n"
      "  --dir DIR           where the scan file goes (default: a temporary directory, removed)\n"
      "  --log-level SPEC    as the daemons take it, e.g. info,Pager=debug\n"
      "  --slow-ms MS        a line for every frame slower than MS: where its time went\n"
      "  --drift-mm MM       a synthetic source: a line for every frame tracked further than MM\n"
      "                      from the truth, with what tracking said of it\n"
      "  --rate HZ           frames come at HZ, as from the capture daemon, into a queue that drops\n"
      "                      the oldest when full (default: every frame, as fast as it is fused)\n"
      "  --queue N           that queue's frames (default 4, the daemon's queue_capacity_frames)\n"
      "  --trace FROM:TO     a synthetic source: a line for every frame whose sequence is in\n"
      "                      FROM..TO, fused or not: tracking, depth's share, error, and its step\n"
      "                      since the frame before against the truth's (mm, world axes), and\n"
      "                      how far the depth moved it from the motion model's prediction\n"
      "A synthetic source's run ends with the worst error per block of the trajectory as the loop\n"
      "closures left it, beside the worst the track had live (err_mm); both aligned at the first\n"
      "frame.\n");
}

bool parse(int argc, char** argv, Options* o) {
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--help" || a == "-h") return false;
    if (i + 1 >= argc) {
      std::fprintf(stderr, "%s needs a value\n", a.c_str());
      return false;
    }
    const char* v = argv[++i];
    if (a == "--source") o->source = v;
    else if (a == "--config") o->config_path = v;
    else if (a == "--dir") o->dir = v;
    else if (a == "--frames") o->frames = std::atol(v);
    else if (a == "--report-every") o->report_every = std::atol(v);
    else if (a == "--slow-ms") o->slow_ms = std::atof(v);
    else if (a == "--drift-mm") o->drift_mm = std::atof(v);
    else if (a == "--rate") o->rate_hz = std::atof(v);
    else if (a == "--queue") o->queue = static_cast<size_t>(std::max(1L, std::atol(v)));
    else if (a == "--trace") {
      unsigned from = 0, to = 0;
      if (std::sscanf(v, "%u:%u", &from, &to) != 2 || to < from) {
        std::fprintf(stderr, "--trace takes FROM:TO, sequence numbers, FROM <= TO\n");
        return false;
      }
      o->trace_from = from;
      o->trace_to = to;
    }
    else if (a == "--log-level") {
      std::string error;
      if (!log::configure(v, &error)) {
        std::fprintf(stderr, "--log-level: %s\n", error.c_str());
        return false;
      }
    }
    else {
      std::fprintf(stderr, "unknown option %s\n", a.c_str());
      return false;
    }
  }
  if (o->source.empty()) std::fprintf(stderr, "--source is required\n");
  return !o->source.empty() && o->frames > 0 && o->report_every > 0;
}

double rss_mib() {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("VmRSS:", 0) == 0) return std::atof(line.c_str() + 6) / 1024.0;
  return 0.0;
}

double counter(const fusiond::CheckpointSink& sink, const std::string& name) {
  std::vector<std::pair<std::string, double>> counters;
  sink.add_counters(&counters);
  for (const auto& [n, v] : counters)
    if (n == name) return v;
  return 0.0;
}

// What became of a frame, in a word or three.
const char* fate(const FrameReport& r) {
  if (r.fused()) return "fused";
  if (r.fusion_shed) return "tracked only";
  return "lost";
}

// Figures since the last report: the frame's whole time and where it went.
struct Block {
  long frames = 0;
  double seconds = 0, max_ms = 0;
  double registration_ms = 0, fusion_ms = 0, store_ms = 0, checkpoint_ms = 0;
  double points_added = 0;
  long shed = 0;         // frames tracked only (their fusion shed)
  double error_mm = -1;  // the largest tracking error (synthetic sources), -1: not known
  LoopClosureStats closer_before;  // the loop closer's totals when the block began
  void add(double s, const FrameReport& r, double process_s) {
    ++frames;
    if (r.fusion_shed) ++shed;
    points_added += static_cast<double>(r.fusion.added);
    seconds += s;
    if (s * 1e3 > max_ms) max_ms = s * 1e3;
    registration_ms += r.registration_ms;
    fusion_ms += r.prefilter_ms + r.deformation_ms + r.fusion_ms;
    store_ms += process_s * 1e3 - (r.prefilter_ms + r.registration_ms + r.deformation_ms + r.fusion_ms);
    checkpoint_ms += (s - process_s) * 1e3;
  }
  double mean(double total) const { return frames ? total / frames : 0.0; }
};

void report(long frame, double wall_s, const Block& b, const fusiond::ScanSession& session,
            const fusiond::CheckpointSink& sink, uint64_t dropped) {
  const IncrementalReconstructor& r = *session.reconstructor();
  const MapDeformation& d = r.deformation();
  const FramePath& path = *session.path();
  const LoopClosureStats closer = path.loop_closure_stats();
  std::printf("%6ld %7.1f %7.1f %7.1f %7.1f %7.1f %8.1f %7.1f %7.1f %9zu %7.1f %7.1f %7.0f %7.0f "
              "%7.0f %5u %5u %8zu %9llu %5zu %5zu %7llu %7.0f %7.1f %6.1f %5llu %5ld\n",
              frame, wall_s, b.mean(b.seconds * 1e3), b.max_ms, b.mean(b.registration_ms),
              b.mean(b.fusion_ms), b.mean(b.store_ms), b.mean(b.checkpoint_ms), rss_mib(),
              r.map().point_count(), counter(sink, "resident_mib"),
              d.memory_bytes() / (1024.0 * 1024.0), counter(sink, "chunks_evicted_total"),
              counter(sink, "chunks_loaded_total"), counter(sink, "chunk_load_collisions"), d.version(),
              d.oldest_version(), d.pending_points(),
              static_cast<unsigned long long>(d.stats().points_merged),
              path.graph().keyframes().size(), path.graph().loops().size(),
              static_cast<unsigned long long>(dropped), b.mean(b.points_added), b.error_mm,
              closer.seconds - b.closer_before.seconds,
              static_cast<unsigned long long>(closer.optimisations - b.closer_before.optimisations),
              b.shed);
  std::fflush(stdout);
}

// The frames to fuse, from the source reopened at its end: read on demand, or (rate_hz > 0) read
// by a thread of their own at that rate into a queue that drops the oldest frame when full.
class FrameFeed {
 public:
  FrameFeed(const Options& o, const AppConfig& config) : options_(o), config_(config) {
    if (o.rate_hz > 0) thread_ = std::thread([this] { produce(); });
  }
  ~FrameFeed() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      stop_ = true;
    }
    cv_.notify_all();
    if (thread_.joinable()) thread_.join();
  }
  FrameFeed(const FrameFeed&) = delete;
  FrameFeed& operator=(const FrameFeed&) = delete;

  Result<Frame> next() {
    if (options_.rate_hz <= 0) return read();
    std::unique_lock<std::mutex> lock(mu_);
    cv_.wait(lock, [&] { return !queue_.empty() || !error_; });
    if (queue_.empty()) return error_;
    Frame f = std::move(queue_.front());
    queue_.pop_front();
    return f;
  }
  uint64_t dropped() const {
    std::lock_guard<std::mutex> lock(mu_);
    return dropped_;
  }
  size_t waiting() const {
    std::lock_guard<std::mutex> lock(mu_);
    return queue_.size();
  }

 private:
  Result<Frame> read() {
    for (;;) {
      if (!source_) {
        auto opened = open_frame_source(options_.source, config_);
        if (!opened) return opened.status();
        source_ = std::move(opened).value();
      }
      auto frame = source_->next();
      if (frame.status().code() != StatusCode::kEndOfStream) return frame;
      source_.reset();  // the loop's next lap
    }
  }
  void produce() {
    const auto period = std::chrono::duration_cast<Clock::duration>(
        std::chrono::duration<double>(1.0 / options_.rate_hz));
    Clock::time_point due = Clock::now();
    for (;;) {
      Result<Frame> frame = read();
      std::this_thread::sleep_until(due);
      due += period;
      std::lock_guard<std::mutex> lock(mu_);
      if (stop_) return;
      if (!frame) {
        error_ = frame.status();
        cv_.notify_all();
        return;
      }
      if (queue_.size() >= options_.queue) {
        queue_.pop_front();
        ++dropped_;
      }
      queue_.push_back(std::move(frame).value());
      cv_.notify_all();
    }
  }

  const Options& options_;
  const AppConfig& config_;
  std::unique_ptr<FrameSource> source_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::deque<Frame> queue_;
  Status error_;
  uint64_t dropped_ = 0;
  bool stop_ = false;
  std::thread thread_;
};

// How far the tracked camera is from the truth, for a synthetic source (whose walk is known): the
// track aligned to the truth at the first frame, as the scan starts wherever the camera is. It
// tells a drifting track from a long scan's cost, which the other columns cannot.
class TruthWitness {
 public:
  explicit TruthWitness(const std::string& source) {
    const std::string prefix = "synthetic:";
    if (source.rfind(prefix, 0) != 0) return;
    auto config = synthetic::parse_synthetic_spec(source.substr(prefix.size()));
    if (!config) return;
    auto sequence = synthetic::SyntheticSequence::create(*config);
    if (sequence) sequence_.emplace(std::move(sequence).value());
  }
  // The true pose of frame `sequence`; none without a truth.
  std::optional<Pose> true_pose(uint32_t sequence) const {
    if (!sequence_ || sequence >= sequence_->size()) return std::nullopt;
    return sequence_->T_world_cam_true(sequence);
  }
  // A tracked pose in the truth's world frame (aligned at the first error_mm() call).
  Pose in_truth_frame(const Pose& T_world_cam) const { return T_true_est_ * T_world_cam; }
  // The error of frame `sequence` fused at T_world_cam, mm; -1 without a truth.
  double error_mm(uint32_t sequence, const Pose& T_world_cam) {
    const std::optional<Pose> truth = true_pose(sequence);
    if (!truth) return -1;
    const Pose& T_true = *truth;
    if (!aligned_) {
      T_true_est_ = T_true * T_world_cam.inverse();
      aligned_ = true;
    }
    return ((T_true_est_ * T_world_cam).translation() - T_true.translation()).norm() * 1e3;
  }

 private:
  std::optional<synthetic::SyntheticSequence> sequence_;
  bool aligned_ = false;
  Pose T_true_est_ = Pose::Identity();
};

// The scan's trajectory as the loop closures left it, against the truth: per block of frames the
// worst error of the poses as corrected beside the worst the track had live. A closure that takes
// a blind stretch's keyframes back shows here and not in the live column; one that does not leaves
// the two alike. Per block (report line): `live_worst`, and `poses_by_block_end`, the trajectory's
// size when the block ended, which says which poses were fused in it.
void report_corrected(const fusiond::ScanSession& session, const std::vector<double>& live_worst,
                      const std::vector<size_t>& poses_by_block_end, long frames_per_block,
                      long frames, TruthWitness* truth) {
  const std::vector<StampedPose>& trajectory = session.trajectory();
  const std::vector<int64_t>& sequences = session.trajectory_sequences();
  if (trajectory.empty() || !truth->true_pose(static_cast<uint32_t>(sequences.front())))
    return;  // no truth
  std::printf("# frames processed  worst live mm   worst corrected mm\n");
  double sum_sq = 0;
  size_t n = 0, i = 0;
  for (size_t b = 0; b < live_worst.size(); ++b) {
    double worst = -1;
    for (; i < poses_by_block_end[b]; ++i) {
      const double e =
          truth->error_mm(static_cast<uint32_t>(sequences[i]), trajectory[i].T_world_cam);
      if (e < 0) continue;  // a sequence past the truth's end
      worst = std::max(worst, e);
      sum_sq += e * e;
      ++n;
    }
    const long first = static_cast<long>(b) * frames_per_block;
    std::printf("# %7ld-%-7ld %16.1f %20.1f\n", first,
                std::min(first + frames_per_block, frames) - 1, live_worst[b], worst);
  }
  std::printf("# the trajectory as corrected, against the truth (aligned at the first frame): RMS "
              "%.1f mm over %zu poses\n",
              n ? std::sqrt(sum_sq / static_cast<double>(n)) : 0.0, n);
}

// --trace: each frame's step since the frame before it, tracked and true, in the truth's world
// frame. Through a stretch where the depth decides nothing of a direction, it shows what the
// motion model carried on against what the camera did (a stop, a turn); and how far the depth
// moved the pose from the motion model's prediction (0 without the prior): where a drift is taken
// back, whether in one frame or over many.
class StepTrace {
 public:
  void frame(uint32_t sequence, const FrameReport& r, bool correction, TruthWitness* truth) {
    const std::optional<Pose> T_true = truth->true_pose(sequence);
    if (!T_true || !r.placed()) return;
    const double error_mm = truth->error_mm(sequence, r.T_world_cam);
    const Eigen::Vector3d p = truth->in_truth_frame(r.T_world_cam).translation() * 1e3;
    const Eigen::Vector3d q = T_true->translation() * 1e3;
    if (last_) {
      const Eigen::Vector3d dp = p - last_->first, dq = q - last_->second;
      std::printf("# trace sequence %u (+%u): %s%s, %s, depth's share %.2f, fitness %.2f, %.0f "
                  "points added, %.1f mm from the truth; step %.1f %.1f %.1f, true %.1f %.1f "
                  "%.1f; %.1f mm from the prediction (chi2 %.1f)\n",
                  sequence, sequence - last_sequence_, fate(r),
                  correction ? " after a correction" : "", to_string(r.tracking),
                  r.registration.data_share, r.registration.fitness,
                  static_cast<double>(r.fusion.added), error_mm, dp.x(), dp.y(), dp.z(), dq.x(),
                  dq.y(), dq.z(), r.registration.prior_innovation.tail<3>().norm() * 1e3,
                  r.registration.prior_chi2);
    }
    last_ = std::make_pair(p, q);
    last_sequence_ = sequence;
  }

 private:
  std::optional<std::pair<Eigen::Vector3d, Eigen::Vector3d>> last_;
  uint32_t last_sequence_ = 0;
};

int run(const Options& o) {
  AppConfig config;
  if (!o.config_path.empty()) {
    auto loaded = load_app_config(o.config_path);
    if (!loaded) {
      DF_LOG(BenchScanSession, Error) << loaded.status().to_string();
      return 2;
    }
    config = std::move(loaded).value();
  }
  // The queue is --queue's, as the daemon's is its --queue's: the shedding rule scales with it.
  config.fusion.queue_capacity_frames = static_cast<int>(o.queue);
  // The daemon's budget and its heap reserve, as depthfuse-fusion takes them before its first frame:
  // without the reserve, the first frame's allocations come from the kernel page by page, and a
  // paced run drops the frames behind it (which the rig does not).
  if (auto st = fusiond::MemoryBudget::of(config).check_and_reserve(); !st.is_ok()) {
    DF_LOG(BenchScanSession, Error) << st.message();
    return 2;
  }
  const bool temporary = o.dir.empty();
  const std::string dir =
      temporary ? (std::filesystem::temp_directory_path() /
                   ("bench-scan-session-" + std::to_string(::getpid())))
                      .string()
                : o.dir;
  std::filesystem::create_directories(dir);
  config.fusion.scan_dir = dir;
  fusiond::SqliteCheckpointSink sink(config, fusiond::SqliteSinkOptions{dir + "/scan.dfscan"});
  fusiond::ScanSession session(config, sink);
  auto started = session.start("bench");
  if (!started) {
    DF_LOG(BenchScanSession, Error) << started.status().to_string();
    return 1;
  }
  std::printf("# %s, %ld frames, config %s, scan file %s/scan.dfscan\n", o.source.c_str(), o.frames,
              o.config_path.empty() ? "(defaults)" : o.config_path.c_str(), dir.c_str());
  std::printf("# frame  wall_s ms_mean  ms_max  reg_ms fuse_ms store_ms ckpt_ms rss_mib map_points res_mib def_mib evicted  loaded "
              "collide  vers  oldest  pending    merged   kfs loops dropped   added  err_mm  lc_s   opt  shed\n");
  const Clock::time_point t0 = Clock::now();
  Block block;
  fusiond::FusionProgress progress;
  FrameFeed feed(o, config);
  TruthWitness truth(o.source);
  StepTrace trace;
  std::vector<double> live_worst;          // per block, for report_corrected()
  std::vector<size_t> poses_by_block_end;  // the same
  for (long n = 0; n < o.frames;) {
    auto frame = feed.next();
    if (!frame) {
      DF_LOG(BenchScanSession, Error) << frame.status().to_string();
      return 1;
    }
    const Clock::time_point f0 = Clock::now();
    const bool shed = o.rate_hz > 0 && config.fusion.shed_fusion(feed.waiting());
    auto outcome =
        session.process(*frame, shed ? FrameWork::kTrackOnly : FrameWork::kTrackAndFuse);
    const double process_s = std::chrono::duration<double>(Clock::now() - f0).count();
    if (!outcome) {
      DF_LOG(BenchScanSession, Error) << "frame " << n << ": " << outcome.status().to_string();
      return 1;
    }
    if (!outcome->store_status)
      DF_LOG(BenchScanSession, Warning) << "frame " << n << ": " << outcome->store_status.to_string();
    ++progress.frames_received;
    if (outcome->report.fused()) ++progress.frames_fused;
    if (session.checkpoint_due()) {
      if (Status st = session.checkpoint("periodic", progress); !st)
        DF_LOG(BenchScanSession, Warning) << "checkpoint: " << st.to_string();
    }
    const double frame_s = std::chrono::duration<double>(Clock::now() - f0).count();
    block.add(frame_s, outcome->report, process_s);
    if (o.traced(frame->sequence))
      trace.frame(frame->sequence, outcome->report, outcome->correction.has_value(), &truth);
    if (outcome->report.fused()) {
      const FrameReport& r = outcome->report;
      const double error_mm = truth.error_mm(frame->sequence, r.T_world_cam);
      block.error_mm = std::max(block.error_mm, error_mm);
      if (o.drift_mm > 0 && error_mm > o.drift_mm)
        std::printf("# drift frame %ld (sequence %u): %.1f mm from the truth; %s, depth's share "
                    "%.2f, fitness %.2f (model %.2f), conditioning %.3g%s%s\n",
                    n, frame->sequence, error_mm, to_string(r.tracking), r.registration.data_share,
                    r.registration.fitness, r.registration.model_fitness,
                    r.registration.conditioning, outcome->correction ? ", after a correction" : "",
                    outcome->keyframe ? ", keyframe" : "");
    }
    if (o.slow_ms > 0 && frame_s * 1e3 > o.slow_ms) {
      const FrameReport& r = outcome->report;
      const double in_process_ms =
          r.prefilter_ms + r.registration_ms + r.deformation_ms + r.fusion_ms;
      std::printf("# slow frame %ld: %.0f ms; prefilter %.0f, registration %.0f (relocalisation "
                  "%.0f), deformation %.0f, fusion %.0f, the rest of process %.0f (the store: "
                  "pager, recorder), checkpoint %.0f; %s%s%s\n",
                  n, frame_s * 1e3, r.prefilter_ms, r.registration_ms, r.relocalisation_ms,
                  r.deformation_ms, r.fusion_ms, process_s * 1e3 - in_process_ms,
                  (frame_s - process_s) * 1e3, outcome->correction ? "after a correction " : "",
                  outcome->keyframe ? "keyframe " : "",
                  r.fused() ? "" : fate(r));
    }
    if (++n % o.report_every == 0 || n == o.frames) {
      report(n, std::chrono::duration<double>(Clock::now() - t0).count(), block, session, sink,
             feed.dropped());
      live_worst.push_back(block.error_mm);
      poses_by_block_end.push_back(session.trajectory().size());
      block = {};
      block.closer_before = session.path()->loop_closure_stats();
    }
  }
  report_corrected(session, live_worst, poses_by_block_end, o.report_every, o.frames, &truth);
  auto saved = session.stop("final", progress);
  if (!saved) DF_LOG(BenchScanSession, Error) << "stop: " << saved.status().to_string();
  else std::printf("# %s\n", saved->message.c_str());
  if (temporary) std::filesystem::remove_all(dir);
  return saved ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  log::set_program_name("bench_scan_session");
  Options o;
  if (!parse(argc, argv, &o)) {
    usage();
    return 2;
  }
  return run(o);
}
