// depthfuse-capture: reads a FrameSource (Kinect V2, TUM folder, synthetic scene, LCM log) and
// publishes its depth (and colour) frames on LCM with sequence numbers, plus a heartbeat at 1 Hz.
// Obeys pause/resume/stop/start addressed to it ("capture" by default). Clean exit on SIGINT/SIGTERM.
// A live source that is unavailable for now (no Kinect plugged in, USB not accessible yet) is waited
// for, never a reason to exit; with a Kinect the heartbeat carries its device state.
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <string>
#include <thread>

#include "depthfuse/app_config.hpp"
#include "depthfuse/base/clock.hpp"
#include "depthfuse/command_t.hpp"
#include "depthfuse/daemon/heartbeat.hpp"
#include "depthfuse/daemon/rate_meter.hpp"
#include "depthfuse/daemon/signals.hpp"
#include "depthfuse/daemon/systemd_notify.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/frame_codec.hpp"
#include "depthfuse/lcm/transport.hpp"
#include "depthfuse/source_factory.hpp"
#if __has_include("depthfuse/lcmlog/lcmlog_source.hpp")
#include "depthfuse/lcmlog/lcmlog_source.hpp"
#define DEPTHFUSE_CAPTURE_HAS_LCMLOG 1
#endif
#if DEPTHFUSE_CAPTURE_HAS_KINECT2  // set by CMakeLists.txt where the kinect2 driver is built
#include "depthfuse/kinect2/kinect2_source.hpp"
#include "kinect2_heartbeat.hpp"
#endif

namespace {

using depthfuse::heartbeat_t;
using Clock = std::chrono::steady_clock;
namespace lcmio = depthfuse::lcmio;
namespace dd = depthfuse::daemon;

void usage(FILE* out) {
  std::fprintf(out,
      "usage: depthfuse-capture [--source SPEC] [--rate HZ|max|recorded] [--loop] [--lcm URL]\n"
      "                         [--config FILE] [--name NAME] [--color zstd|raw|jpeg|none]\n"
      "                         [--depth-encoding zstd|raw] [--depth-unit M] [--linger]\n"
      "  --source SPEC   tum:<folder> | synthetic:<corner|room>[?frames=N&...] | kinect2[:serial]\n"
      "                  | lcmlog:<file>   (default: the config's capture.source)\n"
      "  --rate          frames per second; 'max' as fast as possible; 'recorded' the pace of the\n"
      "                  frame timestamps (default for lcmlog). Default: the source's own rate,\n"
      "                  else the config's capture.rate_hz\n"
      "  --loop          rewind a finite source at its end\n"
      "  --lcm URL       LCM URL (default: the config's lcm.url)\n"
      "  --name NAME     heartbeat name and command target (default: capture)\n"
      "  --depth-unit M  metres per depth count on the wire (default 0.001; 0.0002 keeps TUM's\n"
      "                  1/5000 m exactly)\n"
      "  --linger        keep running (heartbeat state 'finished') when a finite source ends\n");
}

struct Options {
  std::string source;
  std::string rate;  // "", number, "max", "recorded"
  bool loop = false;
  bool loop_set = false;
  std::string lcm_url;
  std::string config_path;
  std::string name = "capture";
  std::string color = "zstd";
  std::string depth_encoding = "zstd";
  std::string depth_unit;  // metres per count on the wire; "" = 0.001
  bool linger = false;
};

bool parse_args(int argc, char** argv, Options* o) {
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&](std::string* dst) {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "depthfuse-capture: %s needs a value\n", a.c_str());
        return false;
      }
      *dst = argv[++i];
      return true;
    };
    if (a == "--help" || a == "-h") {
      usage(stdout);
      std::exit(0);
    } else if (a == "--source") {
      if (!value(&o->source)) return false;
    } else if (a == "--rate") {
      if (!value(&o->rate)) return false;
    } else if (a == "--loop") {
      o->loop = o->loop_set = true;
    } else if (a == "--lcm") {
      if (!value(&o->lcm_url)) return false;
    } else if (a == "--config") {
      if (!value(&o->config_path)) return false;
    } else if (a == "--name") {
      if (!value(&o->name)) return false;
    } else if (a == "--color") {
      if (!value(&o->color)) return false;
    } else if (a == "--depth-unit") {
      if (!value(&o->depth_unit)) return false;
    } else if (a == "--depth-encoding") {
      if (!value(&o->depth_encoding)) return false;
    } else if (a == "--linger") {
      o->linger = true;
    } else {
      std::fprintf(stderr, "depthfuse-capture: unknown option '%s'\n", a.c_str());
      return false;
    }
  }
  return true;
}

enum class Pacing { kFixed, kMax, kRecorded };

constexpr double kStuckSourceS = 10.0;
// A source whose next() said kUnavailable is asked again after at least this long (counted from
// the call: a driver that already waited inside next(), like the Kinect's, is asked again at once).
constexpr double kUnavailableRetryS = 0.5;
// A Kinect source that could not be opened because USB is not accessible is tried again this often.
constexpr double kOpenRetryS = 2.0;

bool is_kinect2_spec(const std::string& spec) {
  return spec == "kinect2" || spec.rfind("kinect2:", 0) == 0;
}

int64_t steady_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch()).count();
}

// Shared between the capture loop, the command thread and the heartbeat.
struct State {
  std::atomic<int8_t> state{heartbeat_t::STATE_STARTING};
  std::atomic<bool> publishing{true};  // false after pause/stop
  std::atomic<int64_t> frames_in{0}, frames_out{0}, source_errors{0};
  std::atomic<int64_t> bytes_out{0};
  std::atomic<int64_t> encode_us{0};
  // When the capture loop entered source->next() (steady clock, ns), 0 when not inside: a driver
  // stuck there for longer than kStuckSourceS stops the systemd watchdog, so systemd restarts us.
  std::atomic<int64_t> in_source_since_ns{0};
  lcmio::ReceiveCounters command_counters;
  dd::RateMeter read_rate, publish_rate;
  std::mutex mutex;  // guards the strings below
  std::string last_error;
  int64_t last_command_id = 0;
  int8_t last_command_result = heartbeat_t::COMMAND_RESULT_NONE;
  std::string last_command_message;
#if DEPTHFUSE_CAPTURE_HAS_KINECT2
  // The Kinect source once it is open; until then (kinect2 requested but not opened yet) the
  // heartbeat reports kinect_unopened (guarded by mutex).
  bool kinect_requested = false;  // set before the service thread starts
  std::atomic<const depthfuse::Kinect2Source*> kinect{nullptr};
  depthfuse::Kinect2Status kinect_unopened;
#endif
};

// Publishes the heartbeat and returns it.
heartbeat_t publish_heartbeat(lcmio::LcmTransport& lcm, const dd::HeartbeatBase& base, State& s) {
  heartbeat_t hb = base.make(s.state.load());
  hb.input_rate_hz = s.read_rate.rate_hz();
  hb.output_rate_hz = s.publish_rate.rate_hz();
  hb.frames_in = s.frames_in.load();
  hb.frames_out = s.frames_out.load();
  hb.messages_malformed = s.command_counters.malformed.load();
  hb.messages_bad_version = s.command_counters.bad_version.load();
  hb.messages_foreign = s.command_counters.foreign.load();
  {
    std::lock_guard<std::mutex> lock(s.mutex);
    hb.last_error = s.last_error;
    hb.last_command_id = s.last_command_id;
    hb.last_command_result = s.last_command_result;
    hb.last_command_message = s.last_command_message;
  }
  const double out = static_cast<double>(std::max<int64_t>(1, hb.frames_out));
  dd::add_counter(&hb, "source_errors", static_cast<double>(s.source_errors.load()));
  dd::add_counter(&hb, "bytes_per_frame", static_cast<double>(s.bytes_out.load()) / out);
  dd::add_counter(&hb, "encode_publish_ms_mean", s.encode_us.load() * 1e-3 / out);
#if DEPTHFUSE_CAPTURE_HAS_KINECT2
  if (s.kinect_requested) {
    depthfuse::Kinect2Status kinect_status;
    if (const auto* kinect = s.kinect.load()) {
      kinect_status = kinect->status();  // thread-safe; not under s.mutex
    } else {
      std::lock_guard<std::mutex> lock(s.mutex);
      kinect_status = s.kinect_unopened;
    }
    depthfuse::capture::annotate_heartbeat(kinect_status, &hb);
  }
#endif
  (void)lcm.publish_message(lcmio::kHeartbeatChannel, hb);
  return hb;
}

void handle_command(const depthfuse::command_t& cmd, const std::string& name, State& s) {
  if (!cmd.target.empty() && cmd.target != name) return;
  std::string message;
  int8_t result = heartbeat_t::COMMAND_RESULT_OK;
  switch (cmd.action) {
    case depthfuse::command_t::ACTION_PAUSE:
    case depthfuse::command_t::ACTION_STOP:
      s.publishing = false;
      message = "publishing paused";
      break;
    case depthfuse::command_t::ACTION_RESUME:
    case depthfuse::command_t::ACTION_START:
      s.publishing = true;
      message = "publishing";
      break;
    default:
      // new scan / checkpoint are the fusion daemon's; only reject when addressed to us.
      if (cmd.target.empty()) return;
      result = heartbeat_t::COMMAND_RESULT_REJECTED;
      message = "capture does not handle this command";
  }
  std::lock_guard<std::mutex> lock(s.mutex);
  s.last_command_id = cmd.command_id;
  s.last_command_result = result;
  s.last_command_message = message;
}

}  // namespace

int main(int argc, char** argv) {
  Options opt;
  if (!parse_args(argc, argv, &opt)) {
    usage(stderr);
    return 2;
  }
  auto& shutdown = dd::ShutdownSignal::install();

  depthfuse::AppConfig config;
  if (!opt.config_path.empty()) {
    auto loaded = depthfuse::load_app_config(opt.config_path);
    if (!loaded) {
      std::fprintf(stderr, "depthfuse-capture: %s\n", loaded.status().to_string().c_str());
      return 2;
    }
    config = std::move(loaded).value();
  }
  const std::string source_spec = opt.source.empty() ? config.capture.source : opt.source;
  const std::string url = opt.lcm_url.empty() ? config.lcm.url : opt.lcm_url;
  const bool loop = opt.loop_set ? opt.loop : config.capture.loop;

  lcmio::DepthEncodeOptions depth_options;
  if (opt.depth_encoding == "raw") {
    depth_options.compress = false;
  } else if (opt.depth_encoding != "zstd") {
    std::fprintf(stderr, "depthfuse-capture: --depth-encoding must be zstd or raw\n");
    return 2;
  }
  if (!opt.depth_unit.empty()) {
    char* end = nullptr;
    depth_options.depth_unit_m = std::strtod(opt.depth_unit.c_str(), &end);
    if (*end != '\0' || !(depth_options.depth_unit_m > 0) || depth_options.depth_unit_m > 1.0) {
      std::fprintf(stderr, "depthfuse-capture: --depth-unit must be metres per count in (0, 1]\n");
      return 2;
    }
  }
  lcmio::ColorEncodeOptions color_options;
  bool send_color = true;
  if (opt.color == "raw") color_options.encoding = lcmio::ColorEncoding::kRaw;
  else if (opt.color == "jpeg") color_options.encoding = lcmio::ColorEncoding::kJpeg;
  else if (opt.color == "none") send_color = false;
  else if (opt.color != "zstd") {
    std::fprintf(stderr, "depthfuse-capture: --color must be zstd, raw, jpeg or none\n");
    return 2;
  }

  std::vector<std::string> warnings;
  auto opened = lcmio::LcmTransport::open(url, &warnings);
  for (const auto& w : warnings) std::fprintf(stderr, "depthfuse-capture: warning: %s\n", w.c_str());
  if (!opened) {
    std::fprintf(stderr, "depthfuse-capture: %s\n", opened.status().to_string().c_str());
    return 1;
  }
  auto lcm = std::move(opened).value();

  Pacing pacing = Pacing::kFixed;
  double rate_hz = config.capture.rate_hz;
  const bool is_log = source_spec.rfind("lcmlog:", 0) == 0;
  if (opt.rate == "max") {
    pacing = Pacing::kMax;
  } else if (opt.rate == "recorded" || (opt.rate.empty() && is_log)) {
    pacing = Pacing::kRecorded;
  } else if (!opt.rate.empty()) {
    char* end = nullptr;
    rate_hz = std::strtod(opt.rate.c_str(), &end);
    if (*end != '\0' || !(rate_hz > 0) || !std::isfinite(rate_hz)) {
      std::fprintf(stderr, "depthfuse-capture: --rate '%s' is not a positive number, max or recorded\n",
                   opt.rate.c_str());
      return 2;
    }
  }

  State s;
  const bool kinect_requested = is_kinect2_spec(source_spec);
#if DEPTHFUSE_CAPTURE_HAS_KINECT2
  s.kinect_requested = kinect_requested;
  s.kinect_unopened.serial = source_spec.size() > 8 ? source_spec.substr(8) : std::string();
  s.kinect_unopened.pipeline = config.capture.kinect2_pipeline;
  s.kinect_unopened.detail = "opening the kinect2 source";
#endif
  dd::HeartbeatBase hb_base(opt.name);
  const std::string name = opt.name;
  lcm->subscribe(lcmio::kCommandChannel, [&](const std::string&, const uint8_t* data, size_t size,
                                             int64_t) {
    depthfuse::command_t cmd;
    const auto r = lcmio::decode_message(data, size, &cmd);
    s.command_counters.count(r);
    if (r != lcmio::DecodeResult::kOk) return;
    handle_command(cmd, name, s);
    if (cmd.target == name) publish_heartbeat(*lcm, hb_base, s);  // the acknowledgement
  });

  std::thread service([&] {
    auto next_hb = Clock::now();
    dd::WatchdogPetter watchdog;
    while (!shutdown.stop_requested()) {
      auto r = lcm->handle(50);
      if (!r) {
        std::lock_guard<std::mutex> lock(s.mutex);
        s.last_error = r.status().message();
      }
      if (Clock::now() >= next_hb) {
        const heartbeat_t hb = publish_heartbeat(*lcm, hb_base, s);
        next_hb += std::chrono::seconds(1);
        if (next_hb < Clock::now()) next_hb = Clock::now() + std::chrono::seconds(1);
        const int64_t since = s.in_source_since_ns.load();
        if (since == 0 || (steady_ns() - since) * 1e-9 < kStuckSourceS) {
          watchdog.pet();
        } else {
          std::lock_guard<std::mutex> lock(s.mutex);
          s.last_error = "the source has not returned a frame for " +
                         std::to_string(static_cast<int>((steady_ns() - since) * 1e-9)) + " s";
          s.state = heartbeat_t::STATE_ERROR;
        }
        dd::notify_status(std::string(dd::state_name(hb.state)) + ", " +
                          std::to_string(hb.frames_out) + " frames published" +
                          (hb.last_error.empty() ? std::string() : "; " + hb.last_error));
      }
    }
  });

  // Open the source. A Kinect whose USB cannot be accessed (yet) is waited for like an absent one.
  std::unique_ptr<depthfuse::FrameSource> source;
  std::string open_error_logged;
  bool told_ready = false;
  int exit_code = 0;
  while (!shutdown.stop_requested()) {
    auto source_r = depthfuse::open_frame_source(source_spec, config);
    if (source_r) {
      source = std::move(source_r).value();
      break;
    }
    const std::string why =
        "cannot open source '" + source_spec + "': " + source_r.status().to_string();
    if (!kinect_requested || source_r.status().code() != depthfuse::StatusCode::kUnavailable) {
      std::fprintf(stderr, "depthfuse-capture: %s\n", why.c_str());
      std::lock_guard<std::mutex> lock(s.mutex);
      s.last_error = why;
      exit_code = 1;
      break;
    }
    if (why != open_error_logged) {
      std::fprintf(stderr, "depthfuse-capture: %s; trying again every %.0f s\n", why.c_str(),
                   kOpenRetryS);
      open_error_logged = why;
    }
    {
      std::lock_guard<std::mutex> lock(s.mutex);
      s.last_error = why;
#if DEPTHFUSE_CAPTURE_HAS_KINECT2
      s.kinect_unopened.detail = source_r.status().message();
#endif
    }
    s.state = heartbeat_t::STATE_IDLE;
    if (!told_ready) {
      dd::notify_ready("waiting for " + source_spec);
      told_ready = true;
    }
    shutdown.sleep_for(kOpenRetryS);
  }
  if (!source) {  // a bad source, or stopped while waiting for one
    s.state = exit_code == 0 ? heartbeat_t::STATE_STOPPING : heartbeat_t::STATE_ERROR;
    dd::notify_stopping();
    publish_heartbeat(*lcm, hb_base, s);
    shutdown.request_stop();
    service.join();
    return exit_code;
  }
  if (!open_error_logged.empty()) {
    std::lock_guard<std::mutex> lock(s.mutex);
    s.last_error.clear();
  }
#if DEPTHFUSE_CAPTURE_HAS_KINECT2
  s.kinect = depthfuse::as_kinect2_source(*source);
#endif
  if (pacing == Pacing::kFixed && opt.rate.empty()) {
    if (auto nominal = source->nominal_rate_hz()) rate_hz = *nominal;
  }
  if (pacing == Pacing::kFixed && !(rate_hz > 0)) pacing = Pacing::kMax;  // rate_hz = 0 in config

  std::fprintf(stderr, "depthfuse-capture: %s -> %s (%s)\n", source->describe().c_str(),
               url.c_str(),
               pacing == Pacing::kMax ? "max rate"
               : pacing == Pacing::kRecorded ? "recorded pace"
                                             : (std::to_string(rate_hz) + " Hz").c_str());
  s.state = heartbeat_t::STATE_RUNNING;
  if (told_ready)
    dd::notify_status("publishing " + source->describe());
  else
    dd::notify_ready("publishing " + source->describe());

  depthfuse::depth_frame_t depth_msg;
  depthfuse::color_frame_t color_msg;
  uint32_t sequence = 0;
  const auto period = pacing == Pacing::kFixed
                          ? std::chrono::duration_cast<Clock::duration>(
                                std::chrono::duration<double>(1.0 / rate_hz))
                          : Clock::duration::zero();
  auto next_tick = Clock::now();
  int64_t prev_utime = 0;
  bool have_prev = false;
  while (!shutdown.stop_requested()) {
    if (!s.publishing.load()) {
      s.state = heartbeat_t::STATE_PAUSED;
      shutdown.sleep_for(0.05);
      next_tick = Clock::now();
      have_prev = false;
      continue;
    }
    s.state = heartbeat_t::STATE_RUNNING;
    const int64_t asked_ns = steady_ns();
    s.in_source_since_ns = asked_ns;
    auto frame_r = source->next();
    s.in_source_since_ns = 0;
    if (!frame_r) {
      const auto code = frame_r.status().code();
      if (code == depthfuse::StatusCode::kEndOfStream) {
        if (loop && source->rewind().is_ok()) {
          have_prev = false;
          continue;
        }
        std::fprintf(stderr, "depthfuse-capture: %s ended after %lld frames\n",
                     source->describe().c_str(), static_cast<long long>(s.frames_out.load()));
        s.state = heartbeat_t::STATE_FINISHED;
        if (!opt.linger) break;
        while (!shutdown.sleep_for(0.2)) {
        }
        break;
      }
      if (code == depthfuse::StatusCode::kUnavailable) {  // a live device is gone for now: wait
#if DEPTHFUSE_CAPTURE_HAS_KINECT2
        const bool kinect = s.kinect.load() != nullptr;
#else
        const bool kinect = false;
#endif
        // A Kinect's own status goes into the heartbeat (state, reason, counters): waiting for a
        // device is not a source error. Any other live source is reported as one.
        if (!kinect) {
          ++s.source_errors;
          s.state = heartbeat_t::STATE_ERROR;
          std::lock_guard<std::mutex> lock(s.mutex);
          s.last_error = frame_r.status().to_string();
        }
        const double waited_s = (steady_ns() - asked_ns) * 1e-9;
        if (waited_s < kUnavailableRetryS) shutdown.sleep_for(kUnavailableRetryS - waited_s);
        continue;
      }
      ++s.source_errors;
      {
        std::lock_guard<std::mutex> lock(s.mutex);
        s.last_error = frame_r.status().to_string();
      }
      std::fprintf(stderr, "depthfuse-capture: %s\n", frame_r.status().to_string().c_str());
      s.state = heartbeat_t::STATE_ERROR;
      exit_code = 1;
      break;
    }
    depthfuse::Frame frame = std::move(frame_r).value();
    ++s.frames_in;
    s.read_rate.add();

    // Pace before publishing, so the publish time is the frame's due time.
    if (pacing == Pacing::kFixed) {
      next_tick += period;
      const auto now = Clock::now();
      if (next_tick > now) {
        if (shutdown.sleep_for(std::chrono::duration<double>(next_tick - now).count())) break;
      } else if (now - next_tick > 10 * period) {
        next_tick = now;  // far behind (slow source): do not burst to catch up
      }
    } else if (pacing == Pacing::kRecorded) {
      // The pace of the recording: lcm-logger's receive times for a log, else the frame times.
      int64_t utime = frame.utime;
#if DEPTHFUSE_CAPTURE_HAS_LCMLOG
      if (const auto* log = dynamic_cast<const depthfuse::LcmLogSource*>(source.get()))
        utime = log->last_log_utime();
#endif
      if (have_prev) {
        const double dt_s = (utime - prev_utime) * 1e-6;
        if (dt_s > 0 && dt_s < 5.0) {
          next_tick += std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(dt_s));
          const auto now = Clock::now();
          if (next_tick > now &&
              shutdown.sleep_for(std::chrono::duration<double>(next_tick - now).count()))
            break;
        } else {
          next_tick = Clock::now();
        }
      } else {
        next_tick = Clock::now();
      }
      prev_utime = utime;
      have_prev = true;
    }

    // Our own sequence numbers: receivers count gaps per publisher, whatever the source numbers.
    frame.sequence = sequence++;
    const auto t0 = Clock::now();
    int64_t bytes = 0;
    if (send_color && !frame.color.empty()) {
      // Colour first: the fusion daemon pairs it with the depth frame that follows.
      auto st = lcmio::encode_color_frame(frame, color_options, &color_msg);
      if (st.is_ok()) {
        st = lcm->publish_message(lcmio::kColorChannel, color_msg);
        bytes += color_msg.getEncodedSize();
      }
      if (!st.is_ok()) {
        std::lock_guard<std::mutex> lock(s.mutex);
        s.last_error = "colour: " + st.to_string();
      }
    }
    auto st = lcmio::encode_depth_frame(frame, depth_options, &depth_msg);
    if (st.is_ok()) {
      depth_msg.publish_utime = depthfuse::now_utime();
      depth_msg.source = source_spec;
      st = lcm->publish_message(lcmio::kDepthChannel, depth_msg);
      bytes += depth_msg.getEncodedSize();
    }
    if (!st.is_ok()) {
      std::lock_guard<std::mutex> lock(s.mutex);
      s.last_error = "depth frame " + std::to_string(frame.sequence) + ": " + st.to_string();
      continue;
    }
    s.encode_us += std::chrono::duration_cast<std::chrono::microseconds>(Clock::now() - t0).count();
    s.bytes_out += bytes;
    ++s.frames_out;
    s.publish_rate.add();
  }

  s.state = heartbeat_t::STATE_STOPPING;
  dd::notify_stopping();
  publish_heartbeat(*lcm, hb_base, s);
  shutdown.request_stop();
  service.join();
  std::fprintf(stderr, "depthfuse-capture: published %lld frames, exiting\n",
               static_cast<long long>(s.frames_out.load()));
  return exit_code;
}
