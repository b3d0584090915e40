// bench_live: how the live appliance performs on this machine.
//  1. Transport cost per frame, in process: depth float->uint16 + zstd, LCM serialisation, and back;
//     bytes on the wire (raw vs zstd depth, zstd vs JPEG colour).
//  2. The fusion daemon (a real depthfuse-fusion process) fed synthetic 512x424 frames at 30 Hz
//     over LCM on loopback for --duration seconds, every frame pre-filtered, re-registered and
//     fused: frames per second fused, drop rate, and latency from publishing a frame to receiving
//     its refined pose (p50, p99), plus the daemon's CPU and memory.
// Frames are rendered and encoded before the run so that the publisher costs nothing during it.
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <numeric>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/daemon/heartbeat.hpp"
#include "depthfuse/daemon/startup.hpp"
#include "depthfuse/depth_frame_t.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/frame_codec.hpp"
#include "depthfuse/lcm/message_auth.hpp"
#include "depthfuse/lcm/transport.hpp"
#include "depthfuse/pose_t.hpp"
#include "depthfuse/synthetic/synthetic_source.hpp"

DF_LOG_CATEGORY(BenchLive)

namespace {

using Clock = std::chrono::steady_clock;
namespace lcm = depthfuse::lcm;

struct Args {
  double duration_s = 60.0;
  double rate_hz = 30.0;
  std::string scene = "corner";
  int distinct_frames = 300;
  int queue = 4;
  std::string config;
  std::string lcm_url;
  std::string fusion = std::string(DEPTHFUSE_BIN_DIR) + "/depthfuse-fusion";
  bool color = true;
  bool hint = true;  // frames carry their true pose as a hint; without, the daemon tracks
  double hint_noise_m = 0.0;  // hints perturbed by N(0, this) per axis, as a front end's would be
};

constexpr const char* kUsage =
    "usage: bench_live [--duration S] [--rate HZ] [--scene corner|room] [--frames N] [--queue N]\n"
    "                  [--config FILE] [--lcm URL] [--fusion PATH] [--no-color]\n"
    "                  [--no-hint | --hint-noise-m X]\n"
    "  --frames N   distinct frames rendered up front; the trajectory loops over them (default 300)\n"
    "  --lcm URL    default: a private loopback port, so a running appliance is not disturbed\n"
    "  --key-file FILE  a rig key for the bench and its daemon (default: none; its bus is its own)\n"
    "  --no-hint    frames without a pose hint, as from a Kinect: the daemon tracks each frame\n"
    "               from the last frames' motion (coarse to fine)\n"
    "  --hint-noise-m X  hints off the true pose by N(0, X) m per axis (default 0: exact)\n";

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const size_t i = std::min(v.size() - 1, static_cast<size_t>(std::lround(p * (v.size() - 1))));
  return v[i];
}

double mean(const std::vector<double>& v) {
  return v.empty() ? std::nan("") : std::accumulate(v.begin(), v.end(), 0.0) / v.size();
}

// utime + stime of a process in seconds (/proc/<pid>/stat), -1 if unreadable.
double cpu_seconds(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string line;
  if (!std::getline(in, line)) return -1;
  const auto close = line.rfind(')');
  if (close == std::string::npos) return -1;
  std::istringstream rest(line.substr(close + 2));
  std::string field;
  long long utime = 0, stime = 0;
  for (int i = 3; i <= 15 && rest >> field; ++i) {
    if (i == 14) utime = std::atoll(field.c_str());
    if (i == 15) stime = std::atoll(field.c_str());
  }
  return static_cast<double>(utime + stime) / static_cast<double>(::sysconf(_SC_CLK_TCK));
}

int run(int argc, char** argv) {
  namespace dd = depthfuse::daemon;
  dd::Startup startup({"bench_live", kUsage,
                       {"duration", "rate", "scene", "frames", "queue", "fusion", "hint-noise-m"},
                       {"no-color", "no-hint"}, {}, 0},
                      argc, argv);
  if (auto code = startup.exit_code()) return *code;
  const dd::Args& args = startup.args();
  Args a;
  long frames = a.distinct_frames, queue = a.queue;
  std::string error;
  if (!args.get_double("duration", &a.duration_s, &error, dd::positive()) ||
      !args.get_double("rate", &a.rate_hz, &error, dd::positive()) ||
      !args.get_int("frames", &frames, &error, dd::NumberRange{2}) ||
      !args.get_int("queue", &queue, &error, dd::NumberRange{1}) ||
      !args.get_double("hint-noise-m", &a.hint_noise_m, &error, dd::NumberRange{0}))
    return startup.usage_error(error);
  a.distinct_frames = static_cast<int>(frames);
  a.queue = static_cast<int>(queue);
  a.scene = args.get("scene", a.scene);
  a.config = args.get("config");
  a.fusion = args.get("fusion", a.fusion);
  a.color = !args.has("no-color");
  a.hint = !args.has("no-hint");
  // By default a private loopback port (from 20000 on, by process id), so that a running
  // appliance is not disturbed.
  if (args.get("lcm").empty()) startup.config().lcm.url = lcm::udpm_url(20000 + ::getpid() % 40000);
  // Without a rig key unless --key-file names one: the bench's bus is its own.
  if (!args.has("key-file")) startup.config().lcm.key_file.clear();
  a.lcm_url = startup.config().lcm.url;

  auto spec = depthfuse::synthetic::parse_synthetic_spec(
      a.scene + "?frames=" + std::to_string(a.distinct_frames) + "&seed=1&rate_hz=" +
      std::to_string(a.rate_hz) + "&pose_noise_m=" + std::to_string(a.hint_noise_m) +
      "&pose_noise_deg=0");
  if (!spec) {
    DF_LOG(BenchLive, Error) << spec.status().to_string();
    return 2;
  }
  auto seq = depthfuse::synthetic::SyntheticSequence::create(*spec);
  if (!seq) {
    DF_LOG(BenchLive, Error) << seq.status().to_string();
    return 2;
  }

  // ---------------------------------------------------------------- 1. transport cost
  std::printf("bench_live: rendering %d frames of synthetic:%s (512x424)...\n", a.distinct_frames,
              a.scene.c_str());
  std::fflush(stdout);
  std::vector<depthfuse::depth_frame_t> depth_msgs(a.distinct_frames);
  std::vector<depthfuse::color_frame_t> color_msgs(a.distinct_frames);
  std::vector<double> convert_ms, compress_ms, serialize_ms, decode_ms, depth_bytes, color_bytes,
      jpeg_bytes, jpeg_ms, color_ms, plain_bytes, plain_ms, sign_verify_ms;
  size_t raw_depth_bytes = 0;
  for (int i = 0; i < a.distinct_frames; ++i) {
    depthfuse::Frame f = seq->render(static_cast<size_t>(i));
    if (!a.hint) f.T_world_cam_hint.reset();  // as from a Kinect: the daemon tracks
    raw_depth_bytes = f.depth.depth_m.size() * 2;
    lcm::CodecTiming t;
    if (!lcm::encode_depth_frame(f, {}, &depth_msgs[i], &t).is_ok()) return 1;
    convert_ms.push_back(t.convert_ms);
    {
      lcm::DepthEncodeOptions plain;
      plain.predict_rows = false;
      depthfuse::depth_frame_t pm;
      lcm::CodecTiming pt;
      if (!lcm::encode_depth_frame(f, plain, &pm, &pt).is_ok()) return 1;
      plain_bytes.push_back(static_cast<double>(pm.data.size()));
      plain_ms.push_back(pt.compress_ms);
    }
    compress_ms.push_back(t.compress_ms);
    auto t0 = Clock::now();
    const auto bytes = lcm::encode_message(depth_msgs[i]);
    serialize_ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
    depth_bytes.push_back(static_cast<double>(bytes.size()));
    t0 = Clock::now();
    depthfuse::depth_frame_t back;
    depthfuse::Frame out;
    if (lcm::decode_message(bytes.data(), bytes.size(), &back) != lcm::DecodeResult::kOk ||
        !lcm::decode_depth_frame(back, &out).is_ok())
      return 1;
    decode_ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
    {
      // The rig key's cost: signing on the sender, verifying on the receiver (a throwaway key).
      lcm::MessageAuth auth(lcm::RigKey::from_bytes({}), 2'000'000);
      std::vector<uint8_t> signed_bytes(bytes);
      signed_bytes.resize(bytes.size() + lcm::kSignatureBytes);
      t0 = Clock::now();
      auth.sign(lcm::kDepthChannel, bytes.data(), bytes.size(), depthfuse::now_utime(),
                signed_bytes.data() + bytes.size());
      const bool verified = auth.verify(lcm::kDepthChannel, signed_bytes.data(),
                                        signed_bytes.size(), depthfuse::now_utime()).ok;
      sign_verify_ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
      if (!verified) return 1;
    }
    if (!f.color.empty()) {
      lcm::CodecTiming ct;
      if (!lcm::encode_color_frame(f, {}, &color_msgs[i], &ct).is_ok()) return 1;
      color_ms.push_back(ct.compress_ms);
      color_bytes.push_back(static_cast<double>(color_msgs[i].getEncodedSize()));
      if (i % 10 == 0) {
        lcm::ColorEncodeOptions jo;
        jo.encoding = lcm::ColorEncoding::kJpeg;
        depthfuse::color_frame_t jm;
        lcm::CodecTiming jt;
        if (!lcm::encode_color_frame(f, jo, &jm, &jt).is_ok()) return 1;
        jpeg_ms.push_back(jt.compress_ms);
        jpeg_bytes.push_back(static_cast<double>(jm.getEncodedSize()));
      }
    }
  }
  std::printf("\ntransport cost per 512x424 frame (mean over %d frames, one core)\n", a.distinct_frames);
  std::printf("  depth float m -> uint16 mm      %7.2f ms\n", mean(convert_ms));
  std::printf("  depth row delta + zstd -1       %7.2f ms   %zu -> %.0f bytes (%.2fx) on the wire\n",
              mean(compress_ms), raw_depth_bytes, mean(depth_bytes),
              raw_depth_bytes / mean(depth_bytes));
  std::printf("  (plain zstd -1, alternative     %7.2f ms   %zu -> %.0f bytes (%.2fx))\n",
              mean(plain_ms), raw_depth_bytes, mean(plain_bytes), raw_depth_bytes / mean(plain_bytes));
  std::printf("  LCM serialisation               %7.2f ms\n", mean(serialize_ms));
  std::printf("  receive: LCM decode + unzstd + uint16 -> float  %7.2f ms\n", mean(decode_ms));
  std::printf("  rig key: sign + verify the depth message  %7.2f ms\n", mean(sign_verify_ms));
  if (!color_ms.empty()) {
    std::printf("  colour RGB8 zstd -1             %7.2f ms   %d -> %.0f bytes\n", mean(color_ms),
                512 * 424 * 3, mean(color_bytes));
    std::printf("  colour JPEG q90 (alternative)   %7.2f ms   %.0f bytes\n", mean(jpeg_ms), mean(jpeg_bytes));
  }
  std::fflush(stdout);

  // ---------------------------------------------------------------- 2. the live daemon
  auto lcm = startup.open_lcm();
  if (!lcm) return 1;
  const std::string scan_dir =
      (std::filesystem::temp_directory_path() / ("bench_live-" + std::to_string(::getpid()))).string();

  std::vector<std::string> fargs = {a.fusion, "--lcm", a.lcm_url, "--autostart", "bench",
                                    "--queue", std::to_string(a.queue), "--scan-dir", scan_dir};
  if (!a.config.empty()) {
    fargs.push_back("--config");
    fargs.push_back(a.config);
  }
  // The daemon signs and verifies with the bench's key (or none, like the bench).
  fargs.push_back("--key-file");
  fargs.push_back(startup.config().lcm.key_file);
  const std::string fusion_log = scan_dir + ".fusion.log";
  const pid_t fusion_pid = ::fork();
  if (fusion_pid == 0) {
    FILE* log = std::fopen(fusion_log.c_str(), "w");
    if (log) {
      ::dup2(fileno(log), 1);
      ::dup2(fileno(log), 2);
    }
    std::vector<char*> cargs;
    for (auto& s : fargs) cargs.push_back(s.data());
    cargs.push_back(nullptr);
    ::execv(cargs[0], cargs.data());
    ::_exit(127);
  }

  std::mutex m;
  std::map<int64_t, int64_t> publish_utime_by_seq;
  std::vector<double> latency_ms, daemon_latency_ms, registered;
  std::vector<double> fitness, rmse_mm, prefilter_ms, registration_ms, fusion_ms;
  depthfuse::heartbeat_t last_hb{};
  bool have_hb = false;
  int64_t poses = 0;
  std::set<int64_t> fused_sequences;
  lcm->subscribe(lcm::kPoseChannel, [&](const std::string&, const uint8_t* d, size_t n, int64_t) {
    const int64_t now = depthfuse::now_utime();
    depthfuse::pose_t p;
    if (lcm::decode_message(d, n, &p) != lcm::DecodeResult::kOk) return;
    std::lock_guard<std::mutex> lock(m);
    ++poses;
    fused_sequences.insert(p.sequence);
    auto it = publish_utime_by_seq.find(p.sequence);
    if (it != publish_utime_by_seq.end()) latency_ms.push_back((now - it->second) * 1e-3);
    daemon_latency_ms.push_back((p.publish_utime - p.frame_publish_utime) * 1e-3);
    registered.push_back(p.registered ? 1.0 : 0.0);
    if (p.registered) {
      fitness.push_back(p.icp_fitness);
      rmse_mm.push_back(p.icp_rmse_m * 1e3);
    }
    prefilter_ms.push_back(p.prefilter_ms);
    registration_ms.push_back(p.registration_ms);
    fusion_ms.push_back(p.fusion_ms);
  });
  lcm->subscribe(lcm::kHeartbeatChannel, [&](const std::string&, const uint8_t* d, size_t n, int64_t) {
    depthfuse::heartbeat_t hb;
    if (lcm::decode_message(d, n, &hb) != lcm::DecodeResult::kOk || hb.name != "fusion") return;
    std::lock_guard<std::mutex> lock(m);
    last_hb = hb;
    have_hb = true;
  });
  std::atomic<bool> stop{false};
  std::thread receiver([&] {
    while (!stop) (void)lcm->handle(20);
  });

  // Wait for the daemon's scan to be running.
  const auto wait_until = Clock::now() + std::chrono::seconds(20);
  for (;;) {
    {
      std::lock_guard<std::mutex> lock(m);
      if (have_hb && last_hb.scan_id == "bench") break;
    }
    if (Clock::now() > wait_until) {
      DF_LOG(BenchLive, Error) << "depthfuse-fusion did not start a scan; its log: " << fusion_log;
      ::kill(fusion_pid, SIGKILL);
      stop = true;
      receiver.join();
      return 1;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }

  std::printf("\nlive: depthfuse-fusion fed %.0f Hz for %.0f s (queue %d, %s)...\n", a.rate_hz,
              a.duration_s, a.queue, a.config.empty() ? "default config" : a.config.c_str());
  std::fflush(stdout);
  const double cpu0 = cpu_seconds(fusion_pid);
  const auto period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / a.rate_hz));
  const auto start = Clock::now();
  auto next = start;
  int64_t published = 0;
  int64_t late_publishes = 0;
  while (Clock::now() - start < std::chrono::duration<double>(a.duration_s)) {
    std::this_thread::sleep_until(next);
    if (Clock::now() - next > period / 2) ++late_publishes;
    next += period;
    const int idx = static_cast<int>(published % a.distinct_frames);
    auto& dm = depth_msgs[idx];
    dm.sequence = published;
    dm.utime = depthfuse::now_utime();
    if (a.color && !color_msgs[idx].data.empty()) {
      color_msgs[idx].sequence = published;
      (void)lcm->publish_message(lcm::kColorChannel, color_msgs[idx]);
    }
    dm.publish_utime = depthfuse::now_utime();
    {
      std::lock_guard<std::mutex> lock(m);
      publish_utime_by_seq[published] = dm.publish_utime;
    }
    (void)lcm->publish_message(lcm::kDepthChannel, dm);
    ++published;
  }
  const double elapsed_s = std::chrono::duration<double>(Clock::now() - start).count();
  std::this_thread::sleep_for(std::chrono::milliseconds(1500));  // the last frames in flight
  const double cpu1 = cpu_seconds(fusion_pid);
  // A final heartbeat with settled counters.
  std::this_thread::sleep_for(std::chrono::milliseconds(1100));
  stop = true;
  receiver.join();
  ::kill(fusion_pid, SIGTERM);
  int status = 0;
  ::waitpid(fusion_pid, &status, 0);
  std::filesystem::remove_all(scan_dir);

  std::lock_guard<std::mutex> lock(m);
  const double fps = poses / elapsed_s;
  std::printf("  published %lld frames in %.1f s (%.2f Hz; %lld publishes late by > half a period)\n",
              static_cast<long long>(published), elapsed_s, published / elapsed_s,
              static_cast<long long>(late_publishes));
  std::printf("  fused     %lld frames: %.2f fps\n", static_cast<long long>(poses), fps);
  std::printf("  received by the daemon %lld, dropped by its queue %lld (%.1f %%), lost in transport %lld\n",
              static_cast<long long>(last_hb.frames_in), static_cast<long long>(last_hb.frames_dropped),
              published ? 100.0 * last_hb.frames_dropped / published : 0.0,
              static_cast<long long>(last_hb.frames_lost));
  // Where the frames without a pose were: the scan's first second (its first frames set up the map
  // and the buffers, and cost several periods) or its steady state.
  const int64_t first_second = static_cast<int64_t>(a.rate_hz);
  int64_t missed_start = 0, missed_after = 0;
  std::string missed_list;  // the steady state's, the first dozen
  for (int64_t seq = 0; seq < published; ++seq) {
    if (fused_sequences.count(seq)) continue;
    if (seq < first_second) {
      ++missed_start;
    } else if (++missed_after <= 12) {
      missed_list += (missed_after == 1 ? " (frames " : " ") + std::to_string(seq);
    }
  }
  if (missed_after > 12) missed_list += " ...";
  if (missed_after > 0) missed_list += ")";
  std::printf("  not fused: %lld in the first second, %lld after it%s\n",
              static_cast<long long>(missed_start), static_cast<long long>(missed_after),
              missed_list.c_str());
  std::printf("  latency publish -> refined pose received: p50 %.1f ms, p99 %.1f ms, max %.1f ms\n",
              percentile(latency_ms, 0.5), percentile(latency_ms, 0.99), percentile(latency_ms, 1.0));
  std::printf("  (daemon side, frame publish -> pose publish: p50 %.1f ms, p99 %.1f ms)\n",
              percentile(daemon_latency_ms, 0.5), percentile(daemon_latency_ms, 0.99));
  std::printf("  per fused frame: pre-filter %.1f ms, re-registration %.1f ms, fusion %.1f ms (means)\n",
              mean(prefilter_ms), mean(registration_ms), mean(fusion_ms));
  std::printf("  registered %.1f %% of frames, ICP fitness %.3f, residual %.2f mm (means)\n",
              100.0 * mean(registered), mean(fitness), mean(rmse_mm));
  // Without hints: how tracking went (the daemon's heartbeat counters; a relocalised frame was lost
  // by tracking, found among the keyframes, and counts as tracked).
  auto counter = [&](const char* key) {
    return static_cast<long long>(depthfuse::daemon::counter_value(last_hb, key));
  };
  std::printf("  tracking: %lld tracked, %lld uncertain, %lld lost (not fused), %lld relocalised\n",
              counter("frames_tracked"), counter("frames_uncertain"),
              counter("frames_lost_tracking"), counter("relocalisations"));
  std::printf("  daemon CPU %.2f cores, RSS %.0f MiB, %lld points in the map at the end\n",
              (cpu1 - cpu0) / elapsed_s, last_hb.rss_bytes / 1048576.0,
              static_cast<long long>(last_hb.point_count));
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return depthfuse::daemon::run_main([&] { return run(argc, argv); });
}
