// The common part of every daemon's heartbeat: name, host, pid, uptime, resident memory, time and
// protocol version. A daemon fills its own counters on top and publishes.
#pragma once

#include <string>

#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/daemon/process_info.hpp"

namespace depthfuse::daemon {

class HeartbeatBase {
 public:
  explicit HeartbeatBase(std::string name) : name_(std::move(name)), host_(host_name()) {}

  // A heartbeat with the common fields filled, counters zero, no custom counters.
  depthfuse::heartbeat_t make(int8_t state) const;
  const std::string& name() const { return name_; }
  double uptime_s() const { return uptime_.seconds(); }

 private:
  std::string name_;
  std::string host_;
  Uptime uptime_;
};

void add_counter(depthfuse::heartbeat_t* hb, const std::string& key, double value);
// The value of a custom counter, or `fallback` when the heartbeat does not carry it.
double counter_value(const depthfuse::heartbeat_t& hb, const std::string& key, double fallback = 0);

const char* state_name(int8_t state);

}  // namespace depthfuse::daemon
