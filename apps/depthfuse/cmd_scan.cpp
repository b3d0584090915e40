// depthfuse scan start|stop|pause|resume|new|checkpoint [NAME] [--target DAEMON] [--lcm URL]:
// sends an operator command and waits for the daemon's acknowledgement in its heartbeat.
#if __has_include("depthfuse/command_t.hpp")
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "command.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/command_t.hpp"
#include "depthfuse/daemon/heartbeat.hpp"
#include "depthfuse/daemon/operator_command.hpp"
#include "depthfuse/daemon/startup.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/transport.hpp"

DF_LOG_CATEGORY(Scan)

namespace {

namespace daemon = depthfuse::daemon;
namespace lcm = depthfuse::lcm;
using depthfuse::command_t;
using depthfuse::heartbeat_t;
using depthfuse::Status;

constexpr const char* kUsage =
    "usage: depthfuse scan start|stop|pause|resume|new|checkpoint [NAME] [--target DAEMON]\n"
    "                      [--lcm URL] [--config FILE] [--timeout S] [--no-wait]\n"
    "  start [NAME]  start a scan (NAME defaults to the time); resumes a paused one\n"
    "  stop          end the scan: the fusion daemon writes its cloud (PLY) and trajectory (TUM)\n"
    "  pause/resume  ignore frames / fuse again, keeping the map\n"
    "  new [NAME]    save the current scan and start another\n"
    "  checkpoint    write a checkpoint now\n"
    "  --target      the daemon to command (default: fusion; \"\" = every daemon)\n"
    "Waits (default 3 s) for the target's acknowledgement and exits 0 if it accepted, 1 if it\n"
    "rejected the command, 3 on timeout.\n";

// What the target answered, as its heartbeats carry it.
struct Answer {
  int result = -1;  // heartbeat_t::COMMAND_RESULT_*; -1: no acknowledgement
  std::string message;
  // The target's count of messages it refused as unsigned, first and last heard: when it grows
  // while no acknowledgement comes, the command was refused for its signature.
  int64_t refused_first = -1, refused_last = -1;
  int sends = 0;
};

// Sends the command until the target acknowledges it or `timeout_s` passes; with `wait` false,
// once. *answer, which the bus's handler fills, must outlive the bus's handling. An error only when
// the bus fails.
Status send(lcm::LcmTransport& bus, const command_t& cmd, const std::string& target,
            double timeout_s, bool wait, Answer* answer) {
  bus.subscribe(lcm::kHeartbeatChannel, [&](const std::string&, const uint8_t* data, size_t size,
                                             int64_t) {
    heartbeat_t hb;
    if (lcm::decode_message(data, size, &hb) != lcm::DecodeResult::kOk) return;
    if (!target.empty() && hb.name != target) return;
    answer->refused_last = daemon::auth_refused_total(hb);
    if (answer->refused_first < 0) answer->refused_first = answer->refused_last;
    if (hb.last_command_id != cmd.command_id) return;
    answer->result = hb.last_command_result;
    answer->message = hb.name + ": " + hb.last_command_message;
  });
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  const auto deadline = start + std::chrono::duration_cast<Clock::duration>(
                                    std::chrono::duration<double>(timeout_s));
  auto next_send = start;
  while (Clock::now() < deadline && answer->result < 0) {
    // UDP may lose the command: resend (same id, the daemon acknowledges it once) every 500 ms.
    if (Clock::now() >= next_send) {
      DF_RETURN_IF_ERROR(bus.publish_message(lcm::kCommandChannel, cmd));
      ++answer->sends;
      next_send = Clock::now() + std::chrono::milliseconds(500);
      if (!wait) return Status::ok();
    }
    auto r = bus.handle(50);
    if (!r) return r.status();
  }
  return Status::ok();
}

// No acknowledgement within the timeout: says the likeliest reason; exit code 3.
int no_answer(const lcm::LcmTransport& bus, const Answer& answer, const std::string& target,
              double timeout_s) {
  char waited[32];
  std::snprintf(waited, sizeof waited, "%.1f", timeout_s);
  if (answer.refused_last > answer.refused_first && answer.refused_first >= 0) {
    DF_LOG(Scan, Error) << "'" << target << "' refused the command: it is not signed with the "
                        << "rig's key ("
                        << (bus.authenticated() ? "this host's key is another one"
                                                : "this host has no key")
                        << "; --key-file or lcm.key_file names it, see docs/protocol.md)";
  } else if (bus.receive_counters().auth.dropped_total() > 0) {
    DF_LOG(Scan, Error) << "no acknowledgement from '" << target << "' within " << waited
                        << " s: what this host hears on the bus is not signed with its key ("
                        << "another rig's key? --key-file or lcm.key_file names it)";
  } else {
    DF_LOG(Scan, Error) << "no acknowledgement from '" << target << "' within " << waited
                        << " s (sent " << answer.sends << " times on " << bus.url()
                        << "): is the daemon running? 'depthfuse status' lists the live ones"
                        << (bus.authenticated() ? "" : "; a rig with a key ignores commands "
                                                       "from a host without it");
  }
  return 3;
}

int cmd_scan(int argc, char** argv) {
  daemon::Startup startup({"depthfuse scan", kUsage, {"target", "timeout"}, {"no-wait"}, {}, 2},
                          argc, argv);
  if (auto code = startup.exit_code()) return *code;
  const daemon::Args& args = startup.args();
  if (args.positional().empty()) return startup.usage_error("which action?");
  int8_t action = 0;
  if (!daemon::parse_action(args.positional()[0], &action))
    return startup.usage_error("unknown action '" + args.positional()[0] + "'");
  double timeout_s = 3.0;
  std::string error;
  if (!args.get_double("timeout", &timeout_s, &error, daemon::positive()))
    return startup.usage_error(error);
  const std::string target = args.get("target", "fusion");
  const bool wait = !args.has("no-wait");
  auto bus = startup.open_lcm();
  if (!bus) return 1;

  const char* user = std::getenv("USER");
  const command_t cmd = daemon::make_command(
      action, target, args.positional().size() > 1 ? args.positional()[1] : std::string(),
      user ? user : "operator");
  Answer answer;
  if (const Status sent = send(*bus, cmd, target, timeout_s, wait, &answer); !sent) {
    DF_LOG(Scan, Error) << sent.to_string();
    return 1;
  }
  if (!wait) return 0;
  if (answer.result < 0) return no_answer(*bus, answer, target, timeout_s);
  if (answer.result == heartbeat_t::COMMAND_RESULT_OK) {
    std::printf("ok: %s\n", answer.message.c_str());
    return 0;
  }
  std::fprintf(stderr, "rejected: %s\n", answer.message.c_str());
  return 1;
}

}  // namespace

DF_REGISTER_COMMAND(scan, "scan", "scan start|stop|pause|resume|new|checkpoint [NAME]",
                    "control the live appliance's scan (sends an LCM command)", cmd_scan);
#endif
