// Parsing and reassembly of udpm datagrams (the protocol is described in udpm.hpp). Runs on the
// thread that receives from the socket; no locks.
#include "depthfuse/lcm/udpm.hpp"

#include <algorithm>
#include <cstring>
#include <utility>

namespace depthfuse::lcm::udpm {
namespace {

uint32_t be32(const uint8_t* p) {
  return (uint32_t{p[0]} << 24) | (uint32_t{p[1]} << 16) | (uint32_t{p[2]} << 8) | uint32_t{p[3]};
}
uint16_t be16(const uint8_t* p) { return static_cast<uint16_t>((p[0] << 8) | p[1]); }

// The channel name that starts at `begin`: its length, or nothing when it has no NUL within the
// datagram and LCM's limit, is empty, or holds a control character.
std::optional<size_t> channel_length(const uint8_t* begin, const uint8_t* end) {
  const size_t room = std::min<size_t>(static_cast<size_t>(end - begin), kMaxChannelBytes + 1);
  const auto* nul = static_cast<const uint8_t*>(std::memchr(begin, 0, room));
  if (!nul || nul == begin) return std::nullopt;
  for (const uint8_t* c = begin; c < nul; ++c) {
    if (*c < 0x20 || *c == 0x7f) return std::nullopt;
  }
  return static_cast<size_t>(nul - begin);
}

}  // namespace

const char* to_string(Drop reason) {
  switch (reason) {
    case Drop::kTooShort: return "too short";
    case Drop::kBadMagic: return "bad magic";
    case Drop::kBadChannel: return "bad channel name";
    case Drop::kBadFragment: return "bad fragment header";
    case Drop::kTooLarge: return "too large";
    case Drop::kInconsistent: return "inconsistent fragment";
    case Drop::kEvicted: return "partial message evicted";
    case Drop::kCount: break;
  }
  return "?";
}

uint64_t Counters::dropped_total() const {
  uint64_t total = 0;
  for (uint64_t n : dropped) total += n;
  return total;
}

Reassembler::Reassembler(Limits limits) : limits_(limits) {}

std::nullopt_t Reassembler::drop(Drop reason) {
  ++counters_.dropped[static_cast<size_t>(reason)];
  return std::nullopt;
}

std::optional<Message> Reassembler::feed(const uint8_t* datagram, size_t size, uint64_t sender) {
  ++counters_.datagrams;
  ++feeds_;
  if (size < kShortHeaderBytes) return drop(Drop::kTooShort);
  switch (be32(datagram)) {
    case kShortMagic: return short_message(datagram, size);
    case kFragmentMagic: return fragment(datagram, size, sender);
    default: return drop(Drop::kBadMagic);
  }
}

std::optional<Message> Reassembler::short_message(const uint8_t* d, size_t size) {
  const uint8_t* end = d + size;
  const uint8_t* channel = d + kShortHeaderBytes;
  const auto length = channel_length(channel, end);
  if (!length) return drop(Drop::kBadChannel);
  const uint8_t* payload = channel + *length + 1;
  const size_t payload_bytes = static_cast<size_t>(end - payload);
  if (payload_bytes > limits_.max_message_bytes) return drop(Drop::kTooLarge);
  const std::string_view name(reinterpret_cast<const char*>(channel), *length);
  if (!wanted(name)) {
    ++counters_.unsubscribed;
    return std::nullopt;
  }
  ++counters_.messages;
  return Message{name, payload, payload_bytes};
}

std::optional<Message> Reassembler::fragment(const uint8_t* d, size_t size, uint64_t sender) {
  if (size < kFragmentHeaderBytes) return drop(Drop::kTooShort);
  const uint32_t sequence = be32(d + 4);
  const uint32_t payload_bytes = be32(d + 8);
  const uint32_t offset = be32(d + 12);
  const uint16_t number = be16(d + 16);
  const uint16_t fragments = be16(d + 18);
  if (fragments == 0 || number >= fragments) return drop(Drop::kBadFragment);
  if (payload_bytes > limits_.max_message_bytes) return drop(Drop::kTooLarge);

  const uint8_t* end = d + size;
  const uint8_t* data = d + kFragmentHeaderBytes;
  std::string_view channel;
  if (number == 0) {
    const auto length = channel_length(data, end);
    if (!length) return drop(Drop::kBadChannel);
    channel = std::string_view(reinterpret_cast<const char*>(data), *length);
    data += *length + 1;
    if (offset != 0) return drop(Drop::kBadFragment);
  }
  const size_t data_bytes = static_cast<size_t>(end - data);
  // 64-bit sums: a 32-bit offset near 2^32 must not wrap past the check.
  if (uint64_t{offset} + data_bytes > payload_bytes) return drop(Drop::kBadFragment);

  // Only fragment 0 names the channel; the filter is asked once per datagram that does.
  const bool unwanted = number == 0 && !wanted(channel);
  auto it = std::find_if(partials_.begin(), partials_.end(),
                         [&](const Partial& p) { return p.sender == sender; });
  if (it != partials_.end() && it->sequence != sequence) {
    erase_partial(static_cast<size_t>(it - partials_.begin()), true);  // the sender moved on
    it = partials_.end();
  }
  Partial* partial = nullptr;
  if (it == partials_.end()) {
    // Fragment 0 first (as liblcm sends them) of a message nobody here wants: nothing is copied.
    partial = start_partial(sender, sequence, payload_bytes, fragments, unwanted);
    if (!partial) return drop(Drop::kTooLarge);
    if (unwanted) {
      ++counters_.unsubscribed;
      return std::nullopt;
    }
  } else {
    partial = &*it;
    if (partial->payload_bytes != payload_bytes || partial->fragments != fragments)
      return drop(Drop::kInconsistent);
  }
  partial->last_feed = feeds_;
  if (partial->unwanted) return std::nullopt;          // a later fragment of an unwanted message
  if (partial->received[number]) return std::nullopt;  // a duplicate: harmless, not counted
  if (unwanted) {
    // Fragment 0 after others: what they brought is let go, the rest will not be copied.
    release(partial);
    ++counters_.unsubscribed;
    return std::nullopt;
  }

  // A message of 0 bytes has no buffer (data() is null), and memcpy must not be given null even
  // for 0 bytes.
  if (data_bytes > 0) std::memcpy(partial->payload.data() + offset, data, data_bytes);
  partial->received[number] = true;
  ++partial->fragments_received;
  partial->bytes_received += data_bytes;
  if (number == 0) partial->channel.assign(channel);
  if (partial->fragments_received < partial->fragments) return std::nullopt;

  const size_t index = static_cast<size_t>(partial - partials_.data());
  if (partial->bytes_received != partial->payload_bytes) {
    erase_partial(index, false);
    return drop(Drop::kInconsistent);
  }
  complete_.swap(partial->payload);
  complete_channel_.swap(partial->channel);
  erase_partial(index, false);
  ++counters_.messages;
  return Message{complete_channel_, complete_.data(), payload_bytes};
}

Reassembler::Partial* Reassembler::start_partial(uint64_t sender, uint32_t sequence,
                                                 uint32_t payload_bytes, uint32_t fragments,
                                                 bool unwanted) {
  // The same limits as for any message, so that a datagram is dropped for the same reasons.
  if (payload_bytes > limits_.max_reassembly_bytes || limits_.max_partial_messages == 0)
    return nullptr;
  const size_t bytes = unwanted ? 0 : payload_bytes;
  // Make room by dropping the partial messages that waited longest for a fragment.
  while (partials_.size() >= limits_.max_partial_messages ||
         reassembly_bytes_ + bytes > limits_.max_reassembly_bytes) {
    const auto oldest = std::min_element(
        partials_.begin(), partials_.end(),
        [](const Partial& a, const Partial& b) { return a.last_feed < b.last_feed; });
    erase_partial(static_cast<size_t>(oldest - partials_.begin()), true);
  }
  Partial& p = partials_.emplace_back();
  p.sender = sender;
  p.sequence = sequence;
  p.payload_bytes = payload_bytes;
  p.fragments = fragments;
  p.unwanted = unwanted;
  if (unwanted) return &p;
  take_spare(payload_bytes, &p.payload);
  // Only a buffer's growth is zeroed: the bytes of a reused one are those of an earlier message
  // until this one's fragments overwrite them. A message completes only once its fragments'
  // sizes add up to its own, so honest fragments cover every byte; overlapping forged ones could
  // leave earlier bus bytes in place, never memory that was not received (and a signed bus
  // rejects the result).
  if (p.payload.size() < payload_bytes) p.payload.resize(payload_bytes);
  p.received.assign(fragments, false);
  reassembly_bytes_ += payload_bytes;
  return &p;
}

void Reassembler::take_spare(size_t bytes, std::vector<uint8_t>* out) {
  // The smallest that holds the message, unless it is much larger (a message in reassembly holds
  // at most about twice its size); else the largest smaller one, which grows.
  const size_t most = 2 * bytes + kMaxDatagramBytes;
  size_t best = spare_.size();
  for (size_t i = 0; i < spare_.size(); ++i) {
    const size_t n = spare_[i].size();
    if (n > most) continue;
    if (best == spare_.size()) { best = i; continue; }
    const size_t b = spare_[best].size();
    const bool fits = n >= bytes, best_fits = b >= bytes;
    if ((fits && (!best_fits || n < b)) || (!fits && !best_fits && n > b)) best = i;
  }
  if (best == spare_.size()) return;
  out->swap(spare_[best]);
  spare_bytes_ -= out->size();
  spare_[best].swap(spare_.back());
  spare_.pop_back();
}

void Reassembler::erase_partial(size_t index, bool evicted) {
  Partial& partial = partials_[index];
  if (evicted && !partial.unwanted) ++counters_.dropped[static_cast<size_t>(Drop::kEvicted)];
  release(&partial);
  partials_.erase(partials_.begin() + static_cast<std::ptrdiff_t>(index));
}

void Reassembler::release(Partial* partial) {
  if (partial->unwanted) return;
  partial->unwanted = true;
  reassembly_bytes_ -= partial->payload_bytes;
  std::vector<uint8_t>& buffer = partial->payload;
  // Kept within the same bounds as the messages in reassembly.
  if (spare_.size() < limits_.max_partial_messages &&
      spare_bytes_ + buffer.size() <= limits_.max_reassembly_bytes) {
    spare_bytes_ += buffer.size();
    spare_.push_back(std::move(buffer));
  }
  buffer = std::vector<uint8_t>();
  partial->received = std::vector<bool>();
  partial->channel.clear();
}

}  // namespace depthfuse::lcm::udpm
