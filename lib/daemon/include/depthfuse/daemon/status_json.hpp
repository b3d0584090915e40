// The monitor's status as JSON: what `depthfuse status --json` prints and what the operator's page
// gets from `GET /api/status`. One object, one line.
#pragma once

#include <string>

#include "depthfuse/status_t.hpp"

namespace depthfuse::daemon {

std::string status_json(const depthfuse::status_t& st);

// A JSON string literal of `s` (quotes included), control characters escaped.
std::string json_string(const std::string& s);
// A JSON number, or null when not finite.
std::string json_number(double v);

}  // namespace depthfuse::daemon
