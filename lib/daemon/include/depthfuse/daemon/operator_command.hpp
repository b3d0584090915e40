// The operator's commands as `depthfuse scan` and the monitor's page send them: the action names,
// and a command_t with a fresh id.
#pragma once

#include <string>

#include "depthfuse/command_t.hpp"

namespace depthfuse::daemon {

// "start", "stop", "pause", "resume", "new", "checkpoint" -> command_t::ACTION_*; false otherwise.
bool parse_action(const std::string& name, int8_t* action);

// A command with a fresh id (time plus randomness, unique enough across operators; > 0) and the
// sender "<user>@<host>".
depthfuse::command_t make_command(int8_t action, const std::string& target,
                                  const std::string& argument, const std::string& user);

}  // namespace depthfuse::daemon
