// The common part of every daemon's heartbeat: name, host, pid, uptime, resident memory, time and
// protocol version. A daemon fills its own counters on top and publishes.
#pragma once

#include <string>
#include <vector>

#include "depthfuse/daemon/process_info.hpp"
#include "depthfuse/frame_source.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/lcm/transport.hpp"
#include "depthfuse/status_t.hpp"

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

// Puts the state of the device a daemon reads into its heartbeat: the device's counters, and when
// the daemon is reading (state running or idle) the state from the device (running while it
// streams, idle while waiting for it, error while it fails) with, unless it streams, its summary
// as hb->last_error. Paused, stopping, finished and error (a stuck driver) are left as they are.
void add_device_status(const DeviceStatus& device, depthfuse::heartbeat_t* hb);

// Puts what the daemon's LCM receiver dropped into its heartbeat: "signed" (1 with a rig key),
// "auth_dropped_<reason>" for each reason authentication drops a message,
// "udpm_dropped_<reason>" for each reason the udpm receiver dropped a datagram at least once, and
// "unsubscribed", once there are some: messages on channels the daemon does not subscribe to,
// left unverified (ReceiveCounters::unsubscribed).
void add_receive_counters(const lcm::LcmTransport& transport, depthfuse::heartbeat_t* hb);

// The messages a daemon refused as not signed with the rig key, by reason ("3 unsigned, 1
// bad_signature"), from its heartbeat; empty when none. And their number.
std::string auth_refusals(const depthfuse::heartbeat_t& hb);
int64_t auth_refused_total(const depthfuse::heartbeat_t& hb);

// The daemons in a status whose heartbeat says they run without a rig key ("signed" 0): their
// messages are neither signed nor verified. In the order of the status.
std::vector<std::string> unsigned_daemons(const depthfuse::status_t& st);

const char* state_name(int8_t state);

}  // namespace depthfuse::daemon
