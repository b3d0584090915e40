// The heartbeat's common fields (see heartbeat.hpp). No state but the daemon's name, host and
// start time; called from whichever thread publishes a heartbeat.
#include "depthfuse/daemon/heartbeat.hpp"

#include "depthfuse/base/clock.hpp"

namespace depthfuse::daemon {

depthfuse::heartbeat_t HeartbeatBase::make(int8_t state) const {
  depthfuse::heartbeat_t hb{};
  hb.protocol_version = depthfuse::heartbeat_t::PROTOCOL_VERSION;
  hb.utime = now_utime();
  hb.name = name_;
  hb.host = host_;
  hb.pid = process_id();
  hb.state = state;
  hb.uptime_s = uptime_.seconds();
  hb.rss_bytes = resident_memory_bytes();
  hb.last_command_result = depthfuse::heartbeat_t::COMMAND_RESULT_NONE;
  hb.num_counters = 0;
  return hb;
}

void add_counter(depthfuse::heartbeat_t* hb, const std::string& key, double value) {
  depthfuse::key_value_t kv;
  kv.key = key;
  kv.value = value;
  hb->counters.push_back(kv);
  hb->num_counters = static_cast<int32_t>(hb->counters.size());
}

double counter_value(const depthfuse::heartbeat_t& hb, const std::string& key, double fallback) {
  for (const auto& kv : hb.counters)
    if (kv.key == key) return kv.value;
  return fallback;
}

void add_device_status(const DeviceStatus& device, depthfuse::heartbeat_t* hb) {
  using depthfuse::heartbeat_t;
  if (hb->state == heartbeat_t::STATE_RUNNING || hb->state == heartbeat_t::STATE_IDLE) {
    switch (device.reading) {
      case DeviceStatus::Reading::kStreaming: hb->state = heartbeat_t::STATE_RUNNING; break;
      case DeviceStatus::Reading::kWaiting: hb->state = heartbeat_t::STATE_IDLE; break;
      case DeviceStatus::Reading::kFailing: hb->state = heartbeat_t::STATE_ERROR; break;
    }
    if (device.reading != DeviceStatus::Reading::kStreaming) hb->last_error = device.summary;
  }
  for (const auto& [key, value] : device.counters) add_counter(hb, key, value);
}

namespace {
constexpr const char* kAuthDroppedPrefix = "auth_dropped_";

// A counter's key from a reason's text: "bad magic" -> "<prefix>bad_magic".
std::string counter_key(const char* prefix, const char* reason) {
  std::string key = std::string(prefix) + reason;
  for (char& c : key)
    if (c == ' ') c = '_';
  return key;
}
}  // namespace

void add_receive_counters(const lcm::LcmTransport& transport, depthfuse::heartbeat_t* hb) {
  const auto counters = transport.receive_counters();
  add_counter(hb, "signed", transport.authenticated() ? 1 : 0);
  if (transport.authenticated()) {
    for (size_t i = 0; i < counters.auth.dropped.size(); ++i)
      add_counter(hb, counter_key(kAuthDroppedPrefix, to_string(static_cast<lcm::AuthDrop>(i))),
                  static_cast<double>(counters.auth.dropped[i]));
  }
  // Not faults: a daemon hears the whole bus. Said only once there are some, like the drops.
  if (counters.unsubscribed > 0)
    add_counter(hb, "unsubscribed", static_cast<double>(counters.unsubscribed));
  for (size_t i = 0; i < counters.udpm.dropped.size(); ++i) {
    if (counters.udpm.dropped[i] == 0) continue;
    add_counter(hb, counter_key("udpm_dropped_", to_string(static_cast<lcm::udpm::Drop>(i))),
                static_cast<double>(counters.udpm.dropped[i]));
  }
}

std::string auth_refusals(const depthfuse::heartbeat_t& hb) {
  std::string text;
  for (const auto& kv : hb.counters) {
    if (kv.key.rfind(kAuthDroppedPrefix, 0) != 0 || kv.value <= 0) continue;
    if (!text.empty()) text += ", ";
    text += std::to_string(static_cast<int64_t>(kv.value)) + " " +
            kv.key.substr(std::string(kAuthDroppedPrefix).size());
  }
  return text;
}

int64_t auth_refused_total(const depthfuse::heartbeat_t& hb) {
  int64_t total = 0;
  for (const auto& kv : hb.counters)
    if (kv.key.rfind(kAuthDroppedPrefix, 0) == 0) total += static_cast<int64_t>(kv.value);
  return total;
}

std::vector<std::string> unsigned_daemons(const depthfuse::status_t& st) {
  std::vector<std::string> names;
  // A heartbeat without the counter says nothing either way.
  for (const auto& d : st.daemons)
    if (counter_value(d.last, "signed", 1) == 0) names.push_back(d.name);
  return names;
}

const char* state_name(int8_t state) {
  switch (state) {
    case depthfuse::heartbeat_t::STATE_STARTING: return "starting";
    case depthfuse::heartbeat_t::STATE_IDLE: return "idle";
    case depthfuse::heartbeat_t::STATE_RUNNING: return "running";
    case depthfuse::heartbeat_t::STATE_PAUSED: return "paused";
    case depthfuse::heartbeat_t::STATE_STOPPING: return "stopping";
    case depthfuse::heartbeat_t::STATE_ERROR: return "error";
    case depthfuse::heartbeat_t::STATE_FINISHED: return "finished";
  }
  return "unknown";
}

}  // namespace depthfuse::daemon
