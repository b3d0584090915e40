#include "depthfuse/lcm/transport.hpp"

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <lcm/lcm.h>
#include <regex.h>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/lcm/host_diagnosis.hpp"
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
             route_fix(parsed->multicast_group);
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
