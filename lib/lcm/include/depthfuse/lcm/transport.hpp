// Opening LCM with a diagnosis instead of LCM's bare self-test failure (host_diagnosis.hpp),
// publishing and receiving raw messages. One LcmTransport per process is typical; publish() may
// be called from any thread, handle() from one thread at a time.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include "depthfuse/lcm/message_auth.hpp"
#include "depthfuse/lcm/udpm.hpp"
#include "depthfuse/lcm/url.hpp"
#include "depthfuse/status.hpp"

typedef struct _lcm_t lcm_t;

namespace depthfuse::lcm {

class UdpmSocket;

// Publishing goes through liblcm. Receiving on an udpm URL goes through depthfuse's own udpm
// receiver (udpm.hpp says why), with every datagram checked before it is used; other providers
// (memq, file) receive through liblcm. With a rig key (authenticate()), every message published
// is signed and every message received is verified before any handler sees it
// (message_auth.hpp); handlers get the payload without its signature either way. A message on a
// channel that no subscription matches is only counted (ReceiveCounters::unsubscribed): it is
// not verified, and on udpm not even reassembled, so that what this process does not read (a
// flood, or capture's own frames heard back) costs it no HMAC.
class LcmTransport {
 public:
  // channel, payload, size, receive time (microseconds, LCM's clock = wall clock)
  using Handler = std::function<void(const std::string& channel, const uint8_t* data, size_t size,
                                     int64_t recv_utime)>;

  // Opens LCM. On failure the status says why and how to fix it (route, URL syntax, ...).
  // Warnings (receive buffer) go to *warnings when given.
  static Result<std::unique_ptr<LcmTransport>> open(const std::string& url,
                                                    std::vector<std::string>* warnings = nullptr);
  ~LcmTransport();
  LcmTransport(const LcmTransport&) = delete;
  LcmTransport& operator=(const LcmTransport&) = delete;

  const std::string& url() const { return url_; }

  // From now on, signs what is published and drops what is received unless it is signed with
  // `key` within `max_skew_us` of this host's clock. Call before handle() runs.
  void authenticate(const RigKey& key, int64_t max_skew_us);
  bool authenticated() const { return auth_ != nullptr; }

  Status publish(const std::string& channel, const void* data, size_t size);

  // Encodes an lcm-gen message and publishes it. Thread-safe.
  template <typename Msg>
  Status publish_message(const std::string& channel, const Msg& msg) {
    std::lock_guard<std::mutex> lock(encode_mutex_);
    const int size = msg.getEncodedSize();
    if (size < 0) return internal_error("cannot size a message for " + channel);
    // Room for the signature after the message, so that it is signed where it was encoded.
    encode_buffer_.resize(static_cast<size_t>(size) + kSignatureBytes);
    // lcm-gen sizes a string by its length but encodes it up to its first NUL, as LCM's strings
    // are C strings: a string holding a NUL (decoded from a forged message, say a heartbeat the
    // monitor copies into its status) encodes shorter. That is the message LCM means: send it.
    const int written = msg.encode(encode_buffer_.data(), 0, size);
    if (written <= 0 || written > size)
      return internal_error("cannot encode a message for " + channel);
    return publish_encoded(channel, &encode_buffer_, static_cast<size_t>(written));
  }

  // channel_regex as in lcm_subscribe ("DEPTHFUSE_.*": the whole channel name must match). Call
  // before handle() runs. An invalid expression (a programming error: channels are constants) is
  // logged and matches nothing.
  void subscribe(const std::string& channel_regex, Handler handler);

  // Waits up to timeout_ms for one message and dispatches it. Returns true when one was handled,
  // false on timeout.
  Result<bool> handle(int timeout_ms);
  // Dispatches messages until `budget_ms` has passed.
  Status handle_for(int budget_ms);

  // What the udpm receiver took in and dropped, by reason (all zero on other providers), and
  // what authentication let through and dropped (all zero without a key). Any thread.
  struct ReceiveCounters {
    udpm::Counters udpm;
    AuthCounters auth;
    // Messages on channels no subscription matches: neither verified nor handed out, and not
    // faults (a daemon hears the whole bus), so in neither of the dropped counts.
    uint64_t unsubscribed = 0;
  };
  ReceiveCounters receive_counters() const;

 private:
  struct Subscription;

  LcmTransport(lcm_t* lcm, std::string url, std::unique_ptr<UdpmSocket> udpm);
  // Publishes (*buffer)[0, payload_size), with a key signed in place in the kSignatureBytes
  // after it, which the buffer holds.
  Status publish_encoded(const std::string& channel, std::vector<uint8_t>* buffer,
                         size_t payload_size);
  Result<bool> handle_udpm(int timeout_ms);
  // Every received message, from either receiver: verified, then handed to the subscriptions
  // whose expression matches its channel.
  void deliver(std::string_view channel, const uint8_t* data, size_t size, int64_t recv_utime);
  void update_counters();
  // The index of the first subscription from `from` on whose expression matches the channel, or
  // subscriptions_.size() when none does.
  size_t first_match(std::string_view channel, size_t from = 0) const;

  lcm_t* lcm_ = nullptr;
  std::string url_;
  std::mutex publish_mutex_;
  std::mutex encode_mutex_;
  std::vector<uint8_t> encode_buffer_;
  std::vector<std::unique_ptr<Subscription>> subscriptions_;
  bool lcm_subscribed_ = false;  // other providers: one catch-all liblcm subscription
  std::unique_ptr<MessageAuth> auth_;

  // The udpm receiver; null on other providers. Used by the thread that calls handle().
  std::unique_ptr<UdpmSocket> udpm_;
  udpm::Reassembler reassembler_;
  uint64_t unsubscribed_ = 0;  // liblcm's receiver: messages no subscription matched
  int uncounted_ = 0;          // datagrams since counters_ was last brought up to date
  mutable std::mutex counters_mutex_;  // guards counters_, a copy for other threads
  ReceiveCounters counters_;
};

}  // namespace depthfuse::lcm
