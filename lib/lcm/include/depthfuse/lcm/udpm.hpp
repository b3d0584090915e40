// LCM's UDP multicast wire protocol, received by depthfuse's own code.
//
// Why not liblcm's receiver: its fragment reassembly (liblcm 1.3.1, Debian 12) checks a
// fragment's offset with 32-bit arithmetic that wraps, and two crafted datagrams make it write
// outside its buffer, so anyone on the network could crash every receiver. Publishing still goes
// through liblcm: what it sends is the protocol by definition.
//
// The protocol (LCM's "UDP Multicast Protocol Description"), all integers big-endian:
//  - a short message is one datagram: magic "LC02", sequence number, the channel name and a NUL,
//    then the payload;
//  - a longer one is cut into fragments, one datagram each: magic "LC03", sequence number, the
//    payload's size, this fragment's offset into the payload, the fragment's number and the
//    number of fragments; fragment 0 carries the channel name and a NUL before its data.
// Every field is checked against the datagram and the limits below before anything is copied or
// allocated; what fails a check is dropped and counted by reason.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace depthfuse::lcm::udpm {

constexpr uint32_t kShortMagic = 0x4c433032;     // "LC02"
constexpr uint32_t kFragmentMagic = 0x4c433033;  // "LC03"
constexpr size_t kShortHeaderBytes = 8;
constexpr size_t kFragmentHeaderBytes = 20;
constexpr size_t kMaxChannelBytes = 63;  // LCM's limit on a channel name
constexpr size_t kMaxDatagramBytes = 65535;

struct Limits {
  // A message that says it is larger is dropped before anything is allocated. The largest the
  // appliance sends is a raw colour frame.
  size_t max_message_bytes = size_t{16} << 20;
  // All messages in reassembly together; past it the oldest partial message is dropped.
  size_t max_reassembly_bytes = size_t{64} << 20;
  // Senders with a message in reassembly at once; past it the oldest partial message is dropped.
  size_t max_partial_messages = 16;
};

enum class Drop : uint8_t {
  kTooShort,           // shorter than its header
  kBadMagic,           // neither LC02 nor LC03
  kBadChannel,         // no NUL within the datagram, empty, too long, or control characters
  kBadFragment,        // fragment number or count out of range, or data beyond the payload
  kTooLarge,           // a payload larger than Limits::max_message_bytes
  kInconsistent,       // disagrees with the earlier fragments of its message
  kEvicted,            // a partial message dropped to make room, or replaced by a newer one
  kCount
};
const char* to_string(Drop reason);

struct Counters {
  uint64_t datagrams = 0;
  uint64_t messages = 0;  // complete messages handed out
  // Well-formed messages on a channel the channel filter refused: not faults, so not in dropped.
  uint64_t unsubscribed = 0;
  std::array<uint64_t, static_cast<size_t>(Drop::kCount)> dropped{};
  uint64_t dropped_total() const;
};

// A complete message. Its views stay valid until the next call to Reassembler::feed.
struct Message {
  std::string_view channel;
  const uint8_t* data = nullptr;
  size_t size = 0;
};

// Turns datagrams into messages. One per socket; not thread-safe.
class Reassembler {
 public:
  explicit Reassembler(Limits limits = {});

  // Which channels are wanted here (the receiver's subscriptions); unset, every channel is. A
  // short message on another channel is counted (Counters::unsubscribed) and not handed out. So
  // is a fragmented one, once its fragment 0 (which alone names the channel) arrives: its buffer
  // is released, and its later fragments are checked as before but not copied. Fragments that
  // arrive before fragment 0 are reassembled as usual until then: nothing else names the channel.
  using ChannelFilter = std::function<bool(std::string_view channel)>;
  void set_channel_filter(ChannelFilter wanted) { wanted_ = std::move(wanted); }

  // One datagram from `sender` (any key that tells senders apart: their address and port).
  // Returns the message this datagram completes, if any.
  std::optional<Message> feed(const uint8_t* datagram, size_t size, uint64_t sender);

  const Counters& counters() const { return counters_; }
  const Limits& limits() const { return limits_; }
  size_t partial_messages() const { return partials_.size(); }
  size_t reassembly_bytes() const { return reassembly_bytes_; }
  size_t spare_bytes() const { return spare_bytes_; }  // buffers kept for reuse

 private:
  struct Partial {
    uint64_t sender = 0;
    uint32_t sequence = 0;
    uint32_t payload_bytes = 0;
    uint32_t fragments = 0;
    uint32_t fragments_received = 0;
    uint64_t bytes_received = 0;
    uint64_t last_feed = 0;  // feed() count when a fragment last arrived: the oldest goes first
    // Fragment 0 named a channel the filter refuses: no buffer, no reassembly bytes; kept only
    // so that the message's other fragments are recognised and skipped.
    bool unwanted = false;
    std::string channel;
    std::vector<uint8_t> payload;  // at least payload_bytes long (a reused buffer may be longer)
    std::vector<bool> received;    // by fragment number
  };

  std::optional<Message> short_message(const uint8_t* d, size_t size);
  std::optional<Message> fragment(const uint8_t* d, size_t size, uint64_t sender);
  // A new partial message; an unwanted one gets no buffer.
  Partial* start_partial(uint64_t sender, uint32_t sequence, uint32_t payload_bytes,
                         uint32_t fragments, bool unwanted);
  // Counts an eviction only of a message that was being reassembled (an unwanted one loses nothing).
  void erase_partial(size_t index, bool evicted);
  // Gives up the partial message's buffer and its reassembly bytes, and marks it unwanted.
  void release(Partial* partial);
  bool wanted(std::string_view channel) const { return !wanted_ || wanted_(channel); }
  // Moves a spare buffer fit for a message of `bytes` into `out` (left alone if none is).
  void take_spare(size_t bytes, std::vector<uint8_t>* out);
  std::nullopt_t drop(Drop reason);

  Limits limits_;
  ChannelFilter wanted_;
  Counters counters_;
  std::vector<Partial> partials_;
  size_t reassembly_bytes_ = 0;
  uint64_t feeds_ = 0;
  std::vector<uint8_t> complete_;  // the last completed message's payload (and maybe more)
  std::string complete_channel_;
  // Buffers of finished partial messages, reused: a flood of first fragments that never complete
  // must not cost an allocation (and the zeroing of up to a whole message) per datagram.
  std::vector<std::vector<uint8_t>> spare_;
  size_t spare_bytes_ = 0;
};

}  // namespace depthfuse::lcm::udpm
