// depthfuse scan start|stop|pause|resume|new|checkpoint [NAME] [--target DAEMON] [--lcm URL]:
// sends an operator command and waits for the daemon's acknowledgement in its heartbeat.
#if __has_include("depthfuse/command_t.hpp")
#include <unistd.h>

#include <chrono>
#include <cinttypes>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>

#include "command.hpp"
#include "depthfuse/app_config.hpp"
#include "depthfuse/command_t.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/transport.hpp"

namespace {

namespace lcmio = depthfuse::lcmio;
using depthfuse::command_t;
using depthfuse::heartbeat_t;

bool parse_action(const std::string& s, int8_t* out) {
  if (s == "start") *out = command_t::ACTION_START;
  else if (s == "stop") *out = command_t::ACTION_STOP;
  else if (s == "pause") *out = command_t::ACTION_PAUSE;
  else if (s == "resume") *out = command_t::ACTION_RESUME;
  else if (s == "new") *out = command_t::ACTION_NEW_SCAN;
  else if (s == "checkpoint") *out = command_t::ACTION_CHECKPOINT_NOW;
  else return false;
  return true;
}

int64_t now_utime() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

void usage(FILE* out) {
  std::fprintf(out,
      "usage: depthfuse scan start|stop|pause|resume|new|checkpoint [NAME] [--target DAEMON]\n"
      "                      [--lcm URL] [--config FILE] [--timeout S] [--no-wait]\n"
      "  start [NAME]  start a scan (NAME defaults to the time); resumes a paused one\n"
      "  stop          end the scan: the fusion daemon writes its cloud (PLY) and trajectory (TUM)\n"
      "  pause/resume  ignore frames / fuse again, keeping the map\n"
      "  new [NAME]    save the current scan and start another\n"
      "  checkpoint    write a checkpoint now\n"
      "  --target      the daemon to command (default: fusion; \"\" = every daemon)\n"
      "Waits (default 3 s) for the target's acknowledgement and exits 0 if it accepted, 1 if it\n"
      "rejected the command, 3 on timeout.\n");
}

int cmd_scan(int argc, char** argv) {
  if (argc < 2 || !std::strcmp(argv[1], "--help") || !std::strcmp(argv[1], "-h")) {
    usage(argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  int8_t action = 0;
  if (!parse_action(argv[1], &action)) {
    std::fprintf(stderr, "depthfuse scan: unknown action '%s'\n", argv[1]);
    usage(stderr);
    return 2;
  }
  std::string target = "fusion", url, config_path, argument;
  double timeout_s = 3.0;
  bool wait = true;
  for (int i = 2; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--target" && i + 1 < argc) target = argv[++i];
    else if (a == "--lcm" && i + 1 < argc) url = argv[++i];
    else if (a == "--config" && i + 1 < argc) config_path = argv[++i];
    else if (a == "--timeout" && i + 1 < argc) timeout_s = std::atof(argv[++i]);
    else if (a == "--no-wait") wait = false;
    else if (!a.empty() && a[0] != '-' && argument.empty()) argument = a;
    else {
      std::fprintf(stderr, "depthfuse scan: bad option '%s'\n", a.c_str());
      return 2;
    }
  }
  depthfuse::AppConfig config;
  if (!config_path.empty()) {
    auto loaded = depthfuse::load_app_config(config_path);
    if (!loaded) {
      std::fprintf(stderr, "depthfuse scan: %s\n", loaded.status().to_string().c_str());
      return 2;
    }
    config = std::move(loaded).value();
  }
  if (url.empty()) url = config.lcm.url;
  auto opened = lcmio::LcmTransport::open(url);
  if (!opened) {
    std::fprintf(stderr, "depthfuse scan: %s\n", opened.status().to_string().c_str());
    return 1;
  }
  auto lcm = std::move(opened).value();

  command_t cmd;
  cmd.protocol_version = command_t::PROTOCOL_VERSION;
  cmd.utime = now_utime();
  // Unique enough across operators: time plus randomness; the daemon echoes it back.
  cmd.command_id = (cmd.utime << 8) ^ static_cast<int64_t>(std::random_device{}() & 0xff);
  if (cmd.command_id <= 0) cmd.command_id = 1;
  cmd.target = target;
  cmd.action = action;
  cmd.argument = argument;
  char host[256] = {0};
  gethostname(host, sizeof(host) - 1);
  const char* user = std::getenv("USER");
  cmd.sender = std::string(user ? user : "operator") + "@" + host;

  int result = -1;
  std::string message;
  lcm->subscribe(lcmio::kHeartbeatChannel, [&](const std::string&, const uint8_t* data, size_t size,
                                               int64_t) {
    heartbeat_t hb;
    if (lcmio::decode_message(data, size, &hb) != lcmio::DecodeResult::kOk) return;
    if (hb.last_command_id != cmd.command_id) return;
    if (!target.empty() && hb.name != target) return;
    result = hb.last_command_result;
    message = hb.name + ": " + hb.last_command_message;
  });

  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  const auto deadline = start + std::chrono::duration_cast<Clock::duration>(
                                    std::chrono::duration<double>(timeout_s));
  auto next_send = start;
  int sends = 0;
  while (Clock::now() < deadline && result < 0) {
    // UDP may lose the command: resend (same id, the daemon acknowledges it once) every 500 ms.
    if (Clock::now() >= next_send) {
      auto st = lcm->publish_message(lcmio::kCommandChannel, cmd);
      if (!st.is_ok()) {
        std::fprintf(stderr, "depthfuse scan: %s\n", st.to_string().c_str());
        return 1;
      }
      ++sends;
      next_send = Clock::now() + std::chrono::milliseconds(500);
      if (!wait) return 0;
    }
    auto r = lcm->handle(50);
    if (!r) {
      std::fprintf(stderr, "depthfuse scan: %s\n", r.status().to_string().c_str());
      return 1;
    }
  }
  if (result < 0) {
    std::fprintf(stderr,
                 "depthfuse scan: no acknowledgement from '%s' within %.1f s (sent %d times on %s): "
                 "is the daemon running? 'depthfuse status' lists the live ones\n",
                 target.c_str(), timeout_s, sends, url.c_str());
    return 3;
  }
  if (result == heartbeat_t::COMMAND_RESULT_OK) {
    std::printf("ok: %s\n", message.c_str());
    return 0;
  }
  std::fprintf(stderr, "rejected: %s\n", message.c_str());
  return 1;
}

}  // namespace

DF_REGISTER_COMMAND(scan, "scan", "scan start|stop|pause|resume|new|checkpoint [NAME]",
                    "control the live appliance's scan (sends an LCM command)", cmd_scan);
#endif
