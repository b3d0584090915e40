#include "depthfuse/daemon/operator_command.hpp"

#include <random>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/daemon/process_info.hpp"

namespace depthfuse::daemon {

bool parse_action(const std::string& s, int8_t* out) {
  using depthfuse::command_t;
  if (s == "start") *out = command_t::ACTION_START;
  else if (s == "stop") *out = command_t::ACTION_STOP;
  else if (s == "pause") *out = command_t::ACTION_PAUSE;
  else if (s == "resume") *out = command_t::ACTION_RESUME;
  else if (s == "new") *out = command_t::ACTION_NEW_SCAN;
  else if (s == "checkpoint") *out = command_t::ACTION_CHECKPOINT_NOW;
  else return false;
  return true;
}

depthfuse::command_t make_command(int8_t action, const std::string& target,
                                  const std::string& argument, const std::string& user) {
  depthfuse::command_t cmd;
  cmd.protocol_version = depthfuse::command_t::PROTOCOL_VERSION;
  cmd.utime = now_utime();
  cmd.command_id = (cmd.utime << 8) ^ static_cast<int64_t>(std::random_device{}() & 0xff);
  if (cmd.command_id <= 0) cmd.command_id = 1;
  cmd.target = target;
  cmd.action = action;
  cmd.argument = argument;
  cmd.sender = user + "@" + host_name();
  return cmd;
}

}  // namespace depthfuse::daemon
