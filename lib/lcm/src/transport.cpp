#include "depthfuse/lcm/transport.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <lcm/lcm.h>
#include <regex.h>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"
#include "udpm_socket.hpp"

DF_LOG_CATEGORY(Lcm)

namespace depthfuse::lcm {

// A channel expression, anchored at both ends as in liblcm, and its handler.
struct LcmTransport::Subscription {
  regex_t regex{};
  bool valid = false;
  Handler handler;
  ~Subscription() {
    if (valid) regfree(&regex);
  }
  bool matches(const char* channel) const {
    return valid && regexec(&regex, channel, 0, nullptr, 0) == 0;
  }
};

namespace {

constexpr const char* kRouteFix =
    "LCM's udpm transport needs a route for the multicast group. Check it with "
    "'ip route get %s' and 'ip route show table all'; on a host where no interface carries "
    "multicast (a bare container, a board without a network cable) add one on loopback: "
    "'sudo ip route add 224.0.0.0/4 dev lo' (tools/lcm/route does this; docs/live.md explains "
    "how to make it permanent)";

std::string format_route_fix(const std::string& group) {
  char text[640];
  std::snprintf(text, sizeof(text), kRouteFix, group.c_str());
  return text;
}

}  // namespace

std::string default_lcm_url() { return "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304"; }

std::string url_with_ttl0(const LcmUrl& url) {
  if (url.provider != "udpm" || url.ttl == 0) return url.text;
  const auto q = url.text.find('?');
  if (q == std::string::npos) return url.text + "?ttl=0";
  std::string query = "&" + url.text.substr(q + 1) + "&";
  const auto at = query.find("&ttl=");
  if (at == std::string::npos) return url.text + "&ttl=0";
  const auto end = query.find('&', at + 1);
  query.replace(at, end - at, "&ttl=0");
  return url.text.substr(0, q + 1) + query.substr(1, query.size() - 2);
}

std::string loopback_test_url(int seed) {
  // Ports 20000..59999, away from LCM's default 7667 and the ephemeral range's usual start.
  const int port = 20000 + (seed < 0 ? -seed : seed) % 40000;
  return "udpm://239.255.76.67:" + std::to_string(port) + "?ttl=0&recv_buf_size=4194304";
}

Result<LcmUrl> parse_lcm_url(const std::string& url) {
  LcmUrl out;
  out.text = url;
  const auto sep = url.find("://");
  if (sep == std::string::npos || sep == 0)
    return invalid_argument("LCM URL '" + url +
                            "' has no provider: expected e.g. " + default_lcm_url());
  out.provider = url.substr(0, sep);
  if (out.provider != "udpm") return out;

  std::string rest = url.substr(sep + 3);
  std::string query;
  if (const auto q = rest.find('?'); q != std::string::npos) {
    query = rest.substr(q + 1);
    rest = rest.substr(0, q);
  }
  std::string host = rest;
  out.port = 7667;
  if (const auto colon = rest.find(':'); colon != std::string::npos) {
    host = rest.substr(0, colon);
    const std::string port_text = rest.substr(colon + 1);
    char* end = nullptr;
    const long port = std::strtol(port_text.c_str(), &end, 10);
    if (port_text.empty() || *end != '\0' || port <= 0 || port > 65535)
      return invalid_argument("LCM URL '" + url + "': port '" + port_text +
                              "' is not a number in 1..65535");
    out.port = static_cast<int>(port);
  }
  out.multicast_group = host.empty() ? "239.255.76.67" : host;
  in_addr addr{};
  if (inet_pton(AF_INET, out.multicast_group.c_str(), &addr) != 1)
    return invalid_argument("LCM URL '" + url + "': '" + out.multicast_group +
                            "' is not an IPv4 address");
  const uint32_t a = ntohl(addr.s_addr);
  if ((a >> 28) != 0xE)
    return invalid_argument("LCM URL '" + url + "': " + out.multicast_group +
                            " is not a multicast address (224.0.0.0/4)");

  size_t pos = 0;
  while (pos <= query.size() && !query.empty()) {
    const auto amp = query.find('&', pos);
    const std::string kv = query.substr(pos, amp == std::string::npos ? std::string::npos : amp - pos);
    const auto eq = kv.find('=');
    const std::string key = kv.substr(0, eq);
    const std::string value = eq == std::string::npos ? std::string() : kv.substr(eq + 1);
    char* end = nullptr;
    if (key == "ttl") {
      const long ttl = std::strtol(value.c_str(), &end, 10);
      if (value.empty() || *end != '\0' || ttl < 0 || ttl > 255)
        return invalid_argument("LCM URL '" + url + "': ttl '" + value + "' is not in 0..255");
      out.ttl = static_cast<int>(ttl);
    } else if (key == "recv_buf_size") {
      const long long size = std::strtoll(value.c_str(), &end, 10);
      if (value.empty() || *end != '\0' || size <= 0)
        return invalid_argument("LCM URL '" + url + "': recv_buf_size '" + value +
                                "' is not a positive number of bytes");
      out.recv_buf_size = size;
    }
    if (amp == std::string::npos) break;
    pos = amp + 1;
  }
  return out;
}

int64_t read_rmem_max() {
  std::ifstream in("/proc/sys/net/core/rmem_max");
  int64_t value = -1;
  if (!(in >> value)) return -1;
  return value;
}

LcmDiagnosis diagnose_lcm_url(const LcmUrl& url) {
  LcmDiagnosis d;
  if (url.provider != "udpm") return d;

  // connect() on a UDP socket asks the kernel for a route without sending anything: ENETUNREACH
  // is exactly the condition under which LCM's self-test fails.
  const int fd = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (fd >= 0) {
    sockaddr_in dest{};
    dest.sin_family = AF_INET;
    dest.sin_port = htons(static_cast<uint16_t>(url.port));
    inet_pton(AF_INET, url.multicast_group.c_str(), &dest.sin_addr);
    if (::connect(fd, reinterpret_cast<const sockaddr*>(&dest), sizeof(dest)) != 0) {
      const int err = errno;
      d.route = unavailable("no route to the LCM multicast group " + url.multicast_group + " (" +
                            std::strerror(err) + "). " + format_route_fix(url.multicast_group));
    }
    ::close(fd);
  }

  const int64_t rmem_max = read_rmem_max();
  if (url.recv_buf_size < 0) {
    d.warnings.push_back(
        "LCM URL '" + url.text + "' sets no recv_buf_size: with the kernel's default receive "
        "buffer most 512x424 depth frames (7-14 UDP fragments each) are lost. Add "
        "'recv_buf_size=4194304' to the URL, e.g. " + default_lcm_url());
  } else if (rmem_max >= 0 && rmem_max < url.recv_buf_size) {
    d.warnings.push_back(
        "net.core.rmem_max is " + std::to_string(rmem_max) + " bytes, smaller than the " +
        std::to_string(url.recv_buf_size) + " the LCM URL asks for: the kernel caps the receive "
        "buffer and large frames will be lost. Raise it with 'sudo sysctl -w "
        "net.core.rmem_max=" + std::to_string(url.recv_buf_size) + "' and make it permanent with "
        "the sysctl drop-in (tools/lcm/sysctl-check --install, see docs/live.md)");
  }
  return d;
}

Result<std::unique_ptr<LcmTransport>> LcmTransport::open(const std::string& url,
                                                        std::vector<std::string>* warnings) {
  auto parsed = parse_lcm_url(url);
  if (!parsed) return parsed.status();
  LcmDiagnosis diagnosis = diagnose_lcm_url(*parsed);
  if (warnings) *warnings = diagnosis.warnings;
  // Without a route LCM would print its self-test failure and give up; say why instead.
  if (!diagnosis.route.is_ok()) return diagnosis.route;

  lcm_t* lcm = lcm_create(url.c_str());
  if (!lcm) {
    std::string why = "cannot open LCM with URL '" + url + "'";
    if (parsed->provider == "udpm") {
      why += ": LCM's multicast self-test failed although a route to " + parsed->multicast_group +
             " exists. Check that the interface of that route has MULTICAST set and is up "
             "('ip link show'), that no firewall drops UDP to port " +
             std::to_string(parsed->port) + ", or use a route on loopback: " +
             format_route_fix(parsed->multicast_group);
    } else {
      why += ": check the provider name and its options (see lcm_create's documentation)";
    }
    return unavailable(why);
  }
  std::unique_ptr<UdpmSocket> udpm;
  if (parsed->provider == "udpm") {
    auto socket = UdpmSocket::open(*parsed);
    if (!socket) {
      lcm_destroy(lcm);
      return socket.status();
    }
    udpm = std::move(socket).value();
  }
  return std::unique_ptr<LcmTransport>(new LcmTransport(lcm, url, std::move(udpm)));
}

LcmTransport::LcmTransport(lcm_t* lcm, std::string url, std::unique_ptr<UdpmSocket> udpm)
    : lcm_(lcm), url_(std::move(url)), udpm_(std::move(udpm)) {
  // A daemon hears every message on the bus (capture its own depth frames, all of them a flood's
  // packets): those on channels it does not subscribe to are not reassembled nor verified.
  reassembler_.set_channel_filter(
      [this](std::string_view channel) { return first_match(channel) < subscriptions_.size(); });
}

LcmTransport::~LcmTransport() {
  if (lcm_) lcm_destroy(lcm_);
}

Status LcmTransport::publish(const std::string& channel, const void* data, size_t size) {
  // A raw payload (tests, tools) is copied once, beside room for its signature.
  std::vector<uint8_t> buffer(size + kSignatureBytes);
  if (size > 0) std::memcpy(buffer.data(), data, size);
  return publish_encoded(channel, &buffer, size);
}

Status LcmTransport::publish_encoded(const std::string& channel, std::vector<uint8_t>* buffer,
                                     size_t payload_size) {
  if (payload_size > static_cast<size_t>(INT32_MAX) - kSignatureBytes)
    return invalid_argument("message too large for LCM");
  size_t size = payload_size;
  if (auth_) {
    auth_->sign(channel, buffer->data(), payload_size, now_utime(), buffer->data() + payload_size);
    size += kSignatureBytes;
  }
  std::lock_guard<std::mutex> lock(publish_mutex_);
  if (lcm_publish(lcm_, channel.c_str(), buffer->data(), static_cast<unsigned int>(size)) != 0)
    return io_error("LCM publish on " + channel + " failed (" + std::to_string(size) +
                    " bytes): " + std::strerror(errno));
  return Status::ok();
}

void LcmTransport::authenticate(const RigKey& key, int64_t max_skew_us) {
  auth_ = std::make_unique<MessageAuth>(key, max_skew_us);
}

void LcmTransport::subscribe(const std::string& channel_regex, Handler handler) {
  auto sub = std::make_unique<Subscription>();
  sub->handler = std::move(handler);
  const std::string anchored = "^(" + channel_regex + ")$";
  sub->valid = regcomp(&sub->regex, anchored.c_str(), REG_EXTENDED | REG_NOSUB) == 0;
  if (!sub->valid) DF_LOG(Lcm, Error) << "invalid LCM channel expression '" << channel_regex << "'";
  // Other providers receive through liblcm, once for all subscriptions: a message is verified
  // once (a second verification would take it for a replay), then matched like udpm's.
  if (!udpm_ && !lcm_subscribed_) {
    lcm_subscribe(
        lcm_, ".*",
        [](const lcm_recv_buf_t* rbuf, const char* channel, void* user) {
          static_cast<LcmTransport*>(user)->deliver(
              channel, static_cast<const uint8_t*>(rbuf->data), rbuf->data_size, rbuf->recv_utime);
        },
        this);
    lcm_subscribed_ = true;
  }
  subscriptions_.push_back(std::move(sub));
}

size_t LcmTransport::first_match(std::string_view channel, size_t from) const {
  // regexec wants a C string; LCM's channel names are short (udpm::kMaxChannelBytes).
  char name[128];
  std::string long_name;
  const char* text = name;
  if (channel.size() < sizeof name) {
    std::memcpy(name, channel.data(), channel.size());
    name[channel.size()] = '\0';
  } else {
    long_name.assign(channel);
    text = long_name.c_str();
  }
  for (size_t i = from; i < subscriptions_.size(); ++i)
    if (subscriptions_[i]->matches(text)) return i;
  return subscriptions_.size();
}

void LcmTransport::deliver(std::string_view channel_view, const uint8_t* data, size_t size,
                           int64_t recv_utime) {
  // The channel first: a message no subscription wants is not worth an HMAC (udpm's reassembler
  // already left these out; liblcm's receiver hands out everything).
  const size_t first = first_match(channel_view);
  if (first == subscriptions_.size()) {
    ++unsubscribed_;
    update_counters();
    return;
  }
  MessageAuth::Verdict verdict;
  if (auth_) {
    verdict = auth_->verify(channel_view, data, size, recv_utime);
  } else {
    verdict.ok = true;
    verdict.payload_size = unsigned_payload_size(data, size);
  }
  update_counters();
  if (!verdict.ok) {
    // The first refusal of each kind is said; the rest are counted (heartbeats carry them).
    if (auth_->counters().dropped[static_cast<size_t>(verdict.reason)] == 1)
      DF_LOG(Lcm, Warning) << "dropped a message on " << channel_view << ": "
                           << to_string(verdict.reason)
                           << " (not signed with this rig's key; further ones are counted)";
    return;
  }
  const std::string channel(channel_view);
  for (size_t i = first; i < subscriptions_.size(); i = first_match(channel, i + 1))
    subscriptions_[i]->handler(channel, data, verdict.payload_size, recv_utime);
}

void LcmTransport::update_counters() {
  std::lock_guard<std::mutex> lock(counters_mutex_);
  counters_.udpm = reassembler_.counters();
  counters_.unsubscribed = unsubscribed_ + reassembler_.counters().unsubscribed;
  if (auth_) counters_.auth = auth_->counters();
}

Result<bool> LcmTransport::handle_udpm(int timeout_ms) {
  const int64_t deadline_ns = steady_ns() + int64_t{timeout_ms} * 1'000'000;
  for (;;) {
    const int64_t left_ms = (deadline_ns - steady_ns()) / 1'000'000;
    auto datagram = udpm_->receive(static_cast<int>(std::max<int64_t>(left_ms, 0)));
    if (!datagram) return datagram.status();
    if (!*datagram) {  // a timeout, or a signal: the caller checks its flags
      update_counters();
      return false;
    }
    const auto& d = **datagram;
    const auto message = reassembler_.feed(d.data, d.size, d.sender);
    if (message) {
      deliver(message->channel, message->data, message->size, now_utime());  // counts it
      return true;
    }
    // Other threads read a copy of the counters, under a lock: taken once per batch of datagrams
    // rather than once per datagram, so a flood of them does not keep it busy.
    if (++uncounted_ >= 64) {
      uncounted_ = 0;
      update_counters();
    }
    if (steady_ns() >= deadline_ns) {
      update_counters();
      return false;
    }
  }
}

LcmTransport::ReceiveCounters LcmTransport::receive_counters() const {
  std::lock_guard<std::mutex> lock(counters_mutex_);
  return counters_;
}

Result<bool> LcmTransport::handle(int timeout_ms) {
  if (udpm_) return handle_udpm(timeout_ms);
  errno = 0;
  const int rc = lcm_handle_timeout(lcm_, timeout_ms);
  // A signal (SIGTERM, SIGINT) interrupts the wait: not an error, the caller checks its flag.
  if (rc < 0 && errno == EINTR) return false;
  if (rc < 0) return io_error("LCM receive failed on '" + url_ + "': " + std::strerror(errno));
  return rc > 0;
}

Status LcmTransport::handle_for(int budget_ms) {
  using clock = std::chrono::steady_clock;
  const auto deadline = clock::now() + std::chrono::milliseconds(budget_ms);
  for (;;) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - clock::now());
    if (left.count() <= 0) return Status::ok();
    auto r = handle(static_cast<int>(left.count()));
    if (!r) return r.status();
  }
}


}  // namespace depthfuse::lcm
