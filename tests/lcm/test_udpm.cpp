// depthfuse's own udpm receiver: the wire format as liblcm sends it, every malformed or hostile
// datagram dropped and counted by reason, memory bounded, and on a real socket the datagrams
// that crashed liblcm's receiver (a fragment whose offset wraps 32 bits) dropped while the
// messages after them still arrive.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cstring>
#include <string>
#include <vector>

#include "depthfuse/lcm/udpm.hpp"
#include "lcm_test_util.hpp"

namespace depthfuse {
namespace {

using namespace depthfuse::testing;
namespace udpm = lcm::udpm;

void put32(std::vector<uint8_t>* out, uint32_t v) {
  for (int shift = 24; shift >= 0; shift -= 8) out->push_back(static_cast<uint8_t>(v >> shift));
}
void put16(std::vector<uint8_t>* out, uint16_t v) {
  out->push_back(static_cast<uint8_t>(v >> 8));
  out->push_back(static_cast<uint8_t>(v));
}

std::vector<uint8_t> short_datagram(const std::string& channel, const std::vector<uint8_t>& payload,
                                    uint32_t sequence = 1) {
  std::vector<uint8_t> d;
  put32(&d, udpm::kShortMagic);
  put32(&d, sequence);
  d.insert(d.end(), channel.begin(), channel.end());
  d.push_back(0);
  d.insert(d.end(), payload.begin(), payload.end());
  return d;
}

std::vector<uint8_t> fragment_datagram(uint32_t sequence, uint32_t payload_bytes, uint32_t offset,
                                       uint16_t number, uint16_t count, const std::string& channel,
                                       const uint8_t* data, size_t size) {
  std::vector<uint8_t> d;
  put32(&d, udpm::kFragmentMagic);
  put32(&d, sequence);
  put32(&d, payload_bytes);
  put32(&d, offset);
  put16(&d, number);
  put16(&d, count);
  if (number == 0) {
    d.insert(d.end(), channel.begin(), channel.end());
    d.push_back(0);
  }
  d.insert(d.end(), data, data + size);
  return d;
}

// A payload cut into fragments the way liblcm cuts it: fragment 0 holds the channel, the offsets
// count payload bytes only.
std::vector<std::vector<uint8_t>> fragments_of(const std::string& channel,
                                               const std::vector<uint8_t>& payload,
                                               size_t fragment_bytes, uint32_t sequence = 7) {
  std::vector<std::vector<uint8_t>> out;
  const size_t first = fragment_bytes - channel.size() - 1;
  std::vector<size_t> starts{0};
  for (size_t at = first; at < payload.size(); at += fragment_bytes) starts.push_back(at);
  for (size_t i = 0; i < starts.size(); ++i) {
    const size_t end = i + 1 < starts.size() ? starts[i + 1] : payload.size();
    out.push_back(fragment_datagram(sequence, static_cast<uint32_t>(payload.size()),
                                    static_cast<uint32_t>(starts[i]), static_cast<uint16_t>(i),
                                    static_cast<uint16_t>(starts.size()), channel,
                                    payload.data() + starts[i], end - starts[i]));
  }
  return out;
}

std::vector<uint8_t> pattern(size_t n) {
  std::vector<uint8_t> p(n);
  for (size_t i = 0; i < n; ++i) p[i] = static_cast<uint8_t>(i * 31 + 7);
  return p;
}

uint64_t dropped(const udpm::Reassembler& r, udpm::Drop reason) {
  return r.counters().dropped[static_cast<size_t>(reason)];
}

TEST(UdpmReassembler, ShortMessage) {
  udpm::Reassembler r;
  const auto d = short_datagram("DEPTHFUSE_POSE", {1, 2, 3});
  const auto m = r.feed(d.data(), d.size(), 1);
  ASSERT_TRUE(m);
  EXPECT_EQ(m->channel, "DEPTHFUSE_POSE");
  ASSERT_EQ(m->size, 3u);
  EXPECT_EQ(m->data[2], 3);
  EXPECT_EQ(r.counters().messages, 1u);
}

TEST(UdpmReassembler, FragmentsInAnyOrderMakeTheMessage) {
  const auto payload = pattern(434'000);
  for (bool reversed : {false, true}) {
    udpm::Reassembler r;
    auto fragments = fragments_of("DEPTHFUSE_DEPTH", payload, 65'000);
    ASSERT_GT(fragments.size(), 6u);
    if (reversed) std::reverse(fragments.begin(), fragments.end());
    std::optional<udpm::Message> m;
    for (size_t i = 0; i < fragments.size(); ++i) {
      m = r.feed(fragments[i].data(), fragments[i].size(), 42);
      if (i + 1 < fragments.size()) {
        EXPECT_FALSE(m) << i;
      }
    }
    ASSERT_TRUE(m);
    EXPECT_EQ(m->channel, "DEPTHFUSE_DEPTH");
    ASSERT_EQ(m->size, payload.size());
    EXPECT_EQ(std::memcmp(m->data, payload.data(), payload.size()), 0);
    EXPECT_EQ(r.partial_messages(), 0u);
    EXPECT_EQ(r.reassembly_bytes(), 0u);
    EXPECT_EQ(r.counters().dropped_total(), 0u);
  }
}

// The two datagrams that crashed every liblcm 1.3.1 receiver: a fragment, then one of the same
// message whose offset is near 2^32, so that offset + size wraps below the payload's size.
TEST(UdpmReassembler, AnOffsetThatWrapsIsDroppedNotWritten) {
  udpm::Reassembler r;
  const auto data = pattern(1000);
  const auto first = fragment_datagram(9, 2000, 0, 0, 2, "DEPTHFUSE_DEPTH", data.data(), 1000);
  const auto evil = fragment_datagram(9, 2000, 0xFFFFFF00u, 1, 2, "", data.data(), 1000);
  EXPECT_FALSE(r.feed(first.data(), first.size(), 1));
  EXPECT_FALSE(r.feed(evil.data(), evil.size(), 1));
  EXPECT_EQ(dropped(r, udpm::Drop::kBadFragment), 1u);
  // The message can still complete with its real second fragment.
  const auto second = fragment_datagram(9, 2000, 1000, 1, 2, "", data.data(), 1000);
  EXPECT_TRUE(r.feed(second.data(), second.size(), 1));
}

TEST(UdpmReassembler, MalformedDatagramsAreCountedByReason) {
  udpm::Reassembler r;
  const auto feed = [&](const std::vector<uint8_t>& d) { return r.feed(d.data(), d.size(), 3); };
  EXPECT_FALSE(feed({0x4c, 0x43, 0x30}));                                   // too short
  EXPECT_FALSE(feed({0, 0, 0, 0, 0, 0, 0, 0, 'A', 0}));                     // bad magic
  auto no_nul = short_datagram("X", {});
  no_nul.pop_back();
  EXPECT_FALSE(feed(no_nul));                                               // no NUL
  EXPECT_FALSE(feed(short_datagram("", {1})));                              // empty channel
  EXPECT_FALSE(feed(short_datagram(std::string(64, 'C'), {1})));            // too long
  EXPECT_FALSE(feed(short_datagram("BAD\nNAME", {1})));                     // control character
  const uint8_t x = 0;
  EXPECT_FALSE(feed(fragment_datagram(1, 10, 0, 2, 2, "", &x, 1)));         // number >= count
  EXPECT_FALSE(feed(fragment_datagram(1, 10, 0, 0, 0, "C", &x, 1)));        // no fragments
  EXPECT_FALSE(feed(fragment_datagram(1, 10, 5, 0, 2, "C", &x, 1)));        // fragment 0 not at 0
  EXPECT_FALSE(feed(fragment_datagram(1, 10, 10, 1, 2, "", &x, 1)));        // beyond the payload
  std::vector<uint8_t> header_only(udpm::kFragmentHeaderBytes - 1, 0);
  header_only[0] = 0x4c, header_only[1] = 0x43, header_only[2] = 0x30, header_only[3] = 0x33;
  EXPECT_FALSE(feed(header_only));                                          // short LC03

  EXPECT_EQ(dropped(r, udpm::Drop::kTooShort), 2u);
  EXPECT_EQ(dropped(r, udpm::Drop::kBadMagic), 1u);
  EXPECT_EQ(dropped(r, udpm::Drop::kBadChannel), 4u);
  EXPECT_EQ(dropped(r, udpm::Drop::kBadFragment), 4u);
  EXPECT_EQ(r.counters().messages, 0u);
  EXPECT_EQ(r.partial_messages(), 0u);
}

TEST(UdpmReassembler, AClaimedSizeBeyondTheLimitAllocatesNothing) {
  udpm::Limits limits;
  limits.max_message_bytes = 1 << 20;
  udpm::Reassembler r(limits);
  const uint8_t x = 0;
  const auto d = fragment_datagram(1, 0xFFFFFFF0u, 0, 0, 60000, "DEPTHFUSE_DEPTH", &x, 1);
  EXPECT_FALSE(r.feed(d.data(), d.size(), 1));
  EXPECT_EQ(dropped(r, udpm::Drop::kTooLarge), 1u);
  EXPECT_EQ(r.reassembly_bytes(), 0u);
}

TEST(UdpmReassembler, PartialMessagesAreBoundedInCountAndBytes) {
  udpm::Limits limits;
  limits.max_message_bytes = 1 << 20;
  limits.max_reassembly_bytes = 3 << 20;
  limits.max_partial_messages = 4;
  udpm::Reassembler r(limits);
  const uint8_t x = 0;
  // A flood of first fragments from 100 senders, each claiming the largest allowed message.
  for (uint64_t sender = 0; sender < 100; ++sender) {
    const auto d = fragment_datagram(1, 1 << 20, 0, 0, 20, "DEPTHFUSE_DEPTH", &x, 1);
    r.feed(d.data(), d.size(), sender);
    ASSERT_LE(r.partial_messages(), 3u);  // the byte limit binds first here
    ASSERT_LE(r.reassembly_bytes(), limits.max_reassembly_bytes);
  }
  EXPECT_EQ(dropped(r, udpm::Drop::kEvicted), 97u);
  // A real message still gets through afterwards.
  const auto payload = pattern(5000);
  std::optional<udpm::Message> m;
  for (const auto& f : fragments_of("DEPTHFUSE_DEPTH", payload, 1400)) m = r.feed(f.data(), f.size(), 500);
  ASSERT_TRUE(m);
  EXPECT_EQ(m->size, payload.size());
}

// Buffers of finished partial messages are reused (a flood of first fragments costs no allocation
// per datagram): each message still comes out exactly, whatever a reused buffer held before, and
// the spare buffers stay within the reassembly limits.
TEST(UdpmReassembler, ReusedBuffersHoldEachMessageExactly) {
  udpm::Limits limits;
  limits.max_reassembly_bytes = 1 << 20;
  limits.max_partial_messages = 4;
  udpm::Reassembler r(limits);
  const uint8_t x = 0xAB;
  uint32_t sequence = 1;
  for (size_t bytes : {300'000u, 20'000u, 310'000u, 5'000u, 299'999u}) {
    // First fragments of messages that never complete, from one sender moving on each time.
    for (int i = 0; i < 50; ++i) {
      const auto d = fragment_datagram(sequence++, static_cast<uint32_t>(bytes), 0, 0, 9,
                                       "DEPTHFUSE_DEPTH", &x, 1);
      EXPECT_FALSE(r.feed(d.data(), d.size(), 3));
    }
    std::vector<uint8_t> payload = pattern(bytes);
    for (uint8_t& b : payload) b ^= static_cast<uint8_t>(bytes);
    std::optional<udpm::Message> m;
    for (const auto& f : fragments_of("DEPTHFUSE_DEPTH", payload, 60'000, sequence++))
      m = r.feed(f.data(), f.size(), 3);
    ASSERT_TRUE(m) << bytes;
    ASSERT_EQ(m->size, bytes);
    EXPECT_EQ(std::memcmp(m->data, payload.data(), bytes), 0) << bytes;
    EXPECT_LE(r.spare_bytes(), limits.max_reassembly_bytes);
  }
}

TEST(UdpmReassembler, AFragmentThatDisagreesWithItsMessageIsDropped) {
  udpm::Reassembler r;
  const auto data = pattern(100);
  const auto a = fragment_datagram(5, 200, 0, 0, 2, "C", data.data(), 100);
  const auto b = fragment_datagram(5, 300, 100, 1, 2, "", data.data(), 100);  // other size
  EXPECT_FALSE(r.feed(a.data(), a.size(), 1));
  EXPECT_FALSE(r.feed(b.data(), b.size(), 1));
  EXPECT_EQ(dropped(r, udpm::Drop::kInconsistent), 1u);
  // A new sequence number from the same sender replaces the partial message.
  const auto c = fragment_datagram(6, 100, 0, 0, 1, "C", data.data(), 100);
  EXPECT_TRUE(r.feed(c.data(), c.size(), 1));
  EXPECT_EQ(dropped(r, udpm::Drop::kEvicted), 1u);
}

// With a channel filter (a receiver's subscriptions), messages on other channels are counted as
// unsubscribed, not handed out, and their fragments not kept: fragment 0 names the channel, so a
// message whose fragment 0 comes first is never copied, and one whose fragment 0 comes last gives
// its buffer back then. A wanted message still completes in any order. None of it is a drop.
TEST(UdpmReassembler, MessagesOnUnwantedChannelsAreCountedNotReassembled) {
  const auto payload = pattern(434'000);
  for (bool reversed : {false, true}) {
    udpm::Reassembler r;
    std::vector<std::string> asked;
    r.set_channel_filter([&](std::string_view channel) {
      asked.emplace_back(channel);
      return channel == "DEPTHFUSE_COMMAND" || channel == "DEPTHFUSE_DEPTH";
    });
    const auto other = short_datagram("DEPTHFUSE_POSE", {1, 2, 3});
    EXPECT_FALSE(r.feed(other.data(), other.size(), 1));
    const auto wanted = short_datagram("DEPTHFUSE_COMMAND", {4, 5});
    const auto m = r.feed(wanted.data(), wanted.size(), 1);
    ASSERT_TRUE(m);
    EXPECT_EQ(m->channel, "DEPTHFUSE_COMMAND");
    EXPECT_EQ(r.counters().unsubscribed, 1u);

    auto unwanted = fragments_of("DEPTHFUSE_COLOR", payload, 65'000, 20);
    if (reversed) std::reverse(unwanted.begin(), unwanted.end());
    for (size_t i = 0; i < unwanted.size(); ++i) {
      EXPECT_FALSE(r.feed(unwanted[i].data(), unwanted[i].size(), 2)) << i;
      const bool zero_seen = reversed ? i + 1 == unwanted.size() : true;
      // Nothing held once fragment 0 has named the channel; before that, what arrived.
      if (zero_seen) {
        EXPECT_EQ(r.reassembly_bytes(), 0u) << i;
      } else {
        EXPECT_EQ(r.reassembly_bytes(), payload.size()) << i;
      }
    }
    EXPECT_EQ(r.counters().unsubscribed, 2u);

    // The same sender's next message is wanted, fragment 0 last in the reversed run.
    auto frames = fragments_of("DEPTHFUSE_DEPTH", payload, 65'000, 21);
    if (reversed) std::reverse(frames.begin(), frames.end());
    std::optional<udpm::Message> depth;
    for (const auto& f : frames) depth = r.feed(f.data(), f.size(), 2);
    ASSERT_TRUE(depth) << reversed;
    EXPECT_EQ(depth->channel, "DEPTHFUSE_DEPTH");
    ASSERT_EQ(depth->size, payload.size());
    EXPECT_EQ(std::memcmp(depth->data, payload.data(), payload.size()), 0);
    EXPECT_EQ(r.counters().messages, 2u);
    EXPECT_EQ(r.counters().unsubscribed, 2u);
    // Leaving an unwanted message behind loses nothing: not an eviction.
    EXPECT_EQ(r.counters().dropped_total(), 0u);
    EXPECT_EQ(r.reassembly_bytes(), 0u);
    // The filter was asked once for each channel name a datagram carried.
    EXPECT_EQ(asked, (std::vector<std::string>{"DEPTHFUSE_POSE", "DEPTHFUSE_COMMAND",
                                               "DEPTHFUSE_COLOR", "DEPTHFUSE_DEPTH"}));
  }
}

// The fragments of an unwanted message are still checked as before: one that disagrees with its
// fragment 0 is dropped and counted, and unwanted messages stay within the bound on partial ones.
TEST(UdpmReassembler, UnwantedFragmentsAreStillCheckedAndBounded) {
  udpm::Limits limits;
  limits.max_partial_messages = 4;
  udpm::Reassembler r(limits);
  r.set_channel_filter([](std::string_view channel) { return channel == "WANTED"; });
  const auto data = pattern(100);
  const auto zero = fragment_datagram(5, 200, 0, 0, 2, "OTHER", data.data(), 100);
  const auto bigger = fragment_datagram(5, 300, 100, 1, 2, "", data.data(), 100);
  const auto wraps = fragment_datagram(5, 200, 0xFFFFFF00u, 1, 2, "", data.data(), 100);
  EXPECT_FALSE(r.feed(zero.data(), zero.size(), 1));
  EXPECT_FALSE(r.feed(bigger.data(), bigger.size(), 1));
  EXPECT_FALSE(r.feed(wraps.data(), wraps.size(), 1));
  EXPECT_EQ(dropped(r, udpm::Drop::kInconsistent), 1u);
  EXPECT_EQ(dropped(r, udpm::Drop::kBadFragment), 1u);
  for (uint64_t sender = 10; sender < 100; ++sender) {
    EXPECT_FALSE(r.feed(zero.data(), zero.size(), sender));
    ASSERT_LE(r.partial_messages(), limits.max_partial_messages);
  }
  EXPECT_EQ(r.counters().unsubscribed, 91u);
  EXPECT_EQ(dropped(r, udpm::Drop::kEvicted), 0u);
  EXPECT_EQ(r.reassembly_bytes(), 0u);
}

// On a real socket: the crafted datagrams go to the transport's port, then a real message
// published through liblcm; the transport drops and counts the first and delivers the second.
TEST(UdpmTransport, HostileDatagramsAreDroppedAndTheBusGoesOn) {
  const std::string url = test_url();
  require_multicast_route(url);
  auto parsed = lcm::parse_lcm_url(url);
  ASSERT_TRUE(parsed.is_ok());
  Listener listener(url);
  ASSERT_TRUE(listener.error().empty()) << listener.error();
  std::atomic<int> received{0};
  std::atomic<size_t> received_bytes{0};
  listener.subscribe("DEPTHFUSE_.*", [&](const std::string&, const uint8_t*, size_t n, int64_t) {
    received_bytes = n;
    ++received;
  });
  listener.start();

  const int fd = ::socket(AF_INET, SOCK_DGRAM, 0);
  ASSERT_GE(fd, 0);
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_port = htons(static_cast<uint16_t>(parsed->port));
  inet_pton(AF_INET, parsed->multicast_group.c_str(), &to.sin_addr);
  const auto data = pattern(1000);
  for (const auto& d : {fragment_datagram(9, 2000, 0, 0, 2, "DEPTHFUSE_DEPTH", data.data(), 1000),
                        fragment_datagram(9, 2000, 0xFFFFFF00u, 1, 2, "", data.data(), 1000),
                        short_datagram(std::string(80, 'X'), {1, 2})}) {
    ASSERT_EQ(::sendto(fd, d.data(), d.size(), 0, reinterpret_cast<const sockaddr*>(&to), sizeof(to)),
              static_cast<ssize_t>(d.size()));
  }
  ::close(fd);

  auto pub = lcm::LcmTransport::open(url);
  ASSERT_TRUE(pub.is_ok()) << pub.status().to_string();
  const auto payload = pattern(300'000);  // fragmented by liblcm
  EXPECT_TRUE(eventually([&] {
    (void)(*pub)->publish("DEPTHFUSE_TEST", payload.data(), payload.size());
    return received > 0;
  }, std::chrono::seconds(5), std::chrono::milliseconds(200)));
  EXPECT_EQ(received_bytes.load(), payload.size());
  const auto counters = listener.lcm()->receive_counters();
  EXPECT_EQ(counters.udpm.dropped[static_cast<size_t>(udpm::Drop::kBadFragment)], 1u);
  EXPECT_EQ(counters.udpm.dropped[static_cast<size_t>(udpm::Drop::kBadChannel)], 1u);
}

// The socket takes queued datagrams in batches: a burst longer than a batch, with datagrams up to
// the largest UDP allows, arrives whole, in order, each with its own bytes and sender.
TEST(UdpmTransport, ABurstOfDatagramsArrivesWholeAndInOrder) {
  const std::string url = test_url();
  require_multicast_route(url);
  auto parsed = lcm::parse_lcm_url(url);
  ASSERT_TRUE(parsed.is_ok());
  auto receiver = lcm::LcmTransport::open(url);
  ASSERT_TRUE(receiver.is_ok()) << receiver.status().to_string();
  std::vector<std::vector<uint8_t>> heard;
  (*receiver)->subscribe("DEPTHFUSE_BURST", [&](const std::string&, const uint8_t* d, size_t n,
                                                 int64_t) { heard.emplace_back(d, d + n); });

  const int fd = ::socket(AF_INET, SOCK_DGRAM, 0);
  ASSERT_GE(fd, 0);
  const int buffer = 4 << 20;
  ::setsockopt(fd, SOL_SOCKET, SO_SNDBUF, &buffer, sizeof(buffer));
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_port = htons(static_cast<uint16_t>(parsed->port));
  inet_pton(AF_INET, parsed->multicast_group.c_str(), &to.sin_addr);
  const std::string channel = "DEPTHFUSE_BURST";
  const size_t largest = 65507 - udpm::kShortHeaderBytes - channel.size() - 1;
  std::vector<std::vector<uint8_t>> sent;
  for (size_t i = 0; i < 40; ++i) {
    std::vector<uint8_t> payload = pattern(i == 17 ? largest : 100 + 37 * i);
    payload[0] = static_cast<uint8_t>(i);
    const auto d = short_datagram(i % 3 == 0 ? "DEPTHFUSE_OTHER" : channel, payload,
                                  static_cast<uint32_t>(i));
    ASSERT_EQ(::sendto(fd, d.data(), d.size(), 0, reinterpret_cast<const sockaddr*>(&to),
                       sizeof(to)),
              static_cast<ssize_t>(d.size())) << i;
    if (i % 3 != 0) sent.push_back(payload);
  }
  ::close(fd);
  EXPECT_TRUE(eventually([&] {
    (void)(*receiver)->handle(20);
    return heard.size() >= sent.size();
  }, std::chrono::seconds(5), std::chrono::milliseconds(1)));
  ASSERT_EQ(heard.size(), sent.size());
  for (size_t i = 0; i < sent.size(); ++i) EXPECT_EQ(heard[i], sent[i]) << i;
  (void)(*receiver)->handle(20);  // the last datagram, unsubscribed, after the last message
  const auto counters = (*receiver)->receive_counters();
  EXPECT_EQ(counters.udpm.datagrams, 40u);
  EXPECT_EQ(counters.unsubscribed, 14u);  // the ones on DEPTHFUSE_OTHER
  EXPECT_EQ(counters.udpm.dropped_total(), 0u);
}

}  // namespace
}  // namespace depthfuse
