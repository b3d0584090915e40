// Datagrams from anyone on the network, into the udpm reassembler. The input is a sequence of
// datagrams, each a 2-byte big-endian length, a sender byte, and that many bytes, so that the
// fuzzer builds fragmented messages from several senders. Small limits make eviction reachable.
// Each complete message then goes through the rig key's verification, as in a keyed receiver.
// Messages on channels the receiver does not want must never come out.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <string_view>

#include "depthfuse/lcm/message_auth.hpp"
#include "depthfuse/lcm/udpm.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  namespace udpm = depthfuse::lcm::udpm;
  udpm::Limits limits;
  limits.max_message_bytes = 1 << 20;
  limits.max_reassembly_bytes = 2 << 20;
  limits.max_partial_messages = 4;
  udpm::Reassembler reassembler(limits);
  // A receiver subscribes to some channels only: by the name's length here, so that the seeds'
  // channels fall on both sides (DEPTHFUSE_DEPTH is left out, DEPTHFUSE_POSE wanted) and the
  // fragments of unwanted messages, before and after their fragment 0, are fuzzed too.
  const auto wanted = [](std::string_view channel) { return channel.size() % 3 != 0; };
  reassembler.set_channel_filter(wanted);
  depthfuse::lcm::MessageAuth auth(depthfuse::lcm::RigKey::from_bytes({}), 2'000'000);
  while (size >= 3) {
    const size_t length = std::min<size_t>((size_t{data[0]} << 8) | data[1], size - 3);
    const uint64_t sender = data[2];
    data += 3;
    size -= 3;
    if (auto m = reassembler.feed(data, length, sender)) {
      // Touch every byte handed out: the sanitizer checks it is inside a live buffer.
      volatile uint8_t sink = 0;
      for (size_t i = 0; i < m->size; ++i) sink = sink ^ m->data[i];
      for (char c : m->channel) sink = sink ^ static_cast<uint8_t>(c);
      if (!wanted(m->channel)) __builtin_trap();
      const auto verdict = auth.verify(m->channel, m->data, m->size, 0);
      if (verdict.ok && verdict.payload_size + depthfuse::lcm::kSignatureBytes != m->size)
        __builtin_trap();
    }
    if (reassembler.reassembly_bytes() > limits.max_reassembly_bytes ||
        reassembler.partial_messages() > limits.max_partial_messages)
      __builtin_trap();
    data += length;
    size -= length;
  }
  return 0;
}
