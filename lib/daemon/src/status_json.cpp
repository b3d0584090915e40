#include "depthfuse/daemon/status_json.hpp"

#include <cinttypes>
#include <cmath>
#include <cstdio>

#include "depthfuse/daemon/heartbeat.hpp"

namespace depthfuse::daemon {

std::string json_string(const std::string& s) {
  std::string out = "\"";
  for (const unsigned char c : s) {
    switch (c) {
      case '"': out += "\\\""; break;
      case '\\': out += "\\\\"; break;
      case '\n': out += "\\n"; break;
      case '\r': out += "\\r"; break;
      case '\t': out += "\\t"; break;
      default:
        if (c < 0x20) {
          char buf[8];
          std::snprintf(buf, sizeof(buf), "\\u%04x", c);
          out += buf;
        } else {
          out += static_cast<char>(c);
        }
    }
  }
  return out + "\"";
}

std::string json_number(double v) {
  if (!std::isfinite(v)) return "null";
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.6g", v);
  return buf;
}

namespace {

// Appends `"key": value` pairs; the first without a comma.
class Fields {
 public:
  explicit Fields(std::string* out) : out_(out) {}
  void raw(const char* key, const std::string& value) {
    *out_ += first_ ? "" : ", ";
    first_ = false;
    *out_ += json_string(key) + ": " + value;
  }
  void str(const char* key, const std::string& v) { raw(key, json_string(v)); }
  void num(const char* key, double v) { raw(key, json_number(v)); }
  void integer(const char* key, int64_t v) { raw(key, std::to_string(v)); }
  void boolean(const char* key, bool v) { raw(key, v ? "true" : "false"); }

 private:
  std::string* out_;
  bool first_ = true;
};

}  // namespace

std::string status_json(const depthfuse::status_t& st) {
  std::string out = "{";
  Fields f(&out);
  f.integer("protocol_version", st.protocol_version);
  f.integer("utime", st.utime);
  f.str("monitor_host", st.monitor_host);
  f.num("stale_after_s", st.stale_after_s);
  f.integer("messages_malformed", st.messages_malformed);
  f.integer("messages_bad_version", st.messages_bad_version);
  f.integer("messages_foreign", st.messages_foreign);
  std::string daemons = "[";
  for (size_t i = 0; i < st.daemons.size(); ++i) {
    const auto& d = st.daemons[i];
    const auto& h = d.last;
    daemons += i ? ", {" : "{";
    Fields g(&daemons);
    g.str("name", d.name);
    g.boolean("alive", d.alive);
    g.num("heartbeat_age_s", d.heartbeat_age_s);
    g.integer("heartbeats", d.heartbeats);
    g.str("host", h.host);
    g.integer("pid", h.pid);
    g.str("state", state_name(h.state));
    g.num("uptime_s", h.uptime_s);
    g.num("input_rate_hz", h.input_rate_hz);
    g.num("output_rate_hz", h.output_rate_hz);
    g.integer("frames_in", h.frames_in);
    g.integer("frames_out", h.frames_out);
    g.integer("frames_dropped", h.frames_dropped);
    g.integer("frames_lost", h.frames_lost);
    g.integer("messages_malformed", h.messages_malformed);
    g.integer("messages_bad_version", h.messages_bad_version);
    g.integer("messages_foreign", h.messages_foreign);
    g.integer("frames_out_of_order", h.frames_out_of_order);
    g.integer("queue_depth", h.queue_depth);
    g.integer("queue_capacity", h.queue_capacity);
    g.integer("point_count", h.point_count);
    g.integer("rss_bytes", h.rss_bytes);
    g.str("scan_id", h.scan_id);
    g.str("last_error", h.last_error);
    g.integer("last_command_id", h.last_command_id);
    g.integer("last_command_result", h.last_command_result);
    g.str("last_command_message", h.last_command_message);
    std::string counters = "{";
    Fields c(&counters);
    for (const auto& kv : h.counters) c.num(kv.key.c_str(), kv.value);
    g.raw("counters", counters + "}");
    daemons += "}";
  }
  f.raw("daemons", daemons + "]");
  // Those without a rig key: the operator is told the bus is open (empty when every one has it).
  std::string open = "[";
  for (const std::string& name : unsigned_daemons(st))
    open += (open.size() > 1 ? ", " : "") + json_string(name);
  f.raw("unsigned_daemons", open + "]");
  return out + "}";
}

}  // namespace depthfuse::daemon
