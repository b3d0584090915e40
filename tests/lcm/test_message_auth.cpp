// The rig key and message signatures: what is signed with the key passes once, and everything else
// (unsigned, another key, an altered byte, another channel, too old, too new, a replay) is dropped
// and counted; over real LCM on loopback, and read by the Python bindings.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <atomic>
#include <fstream>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/message_auth.hpp"
#include "depthfuse/lcm/transport.hpp"
#include "lcm_test_util.hpp"

namespace depthfuse {
namespace {

using lcm::AuthDrop;
using lcm::kSignatureBytes;
using lcm::MessageAuth;
using lcm::RigKey;

RigKey key_of(uint8_t fill) {
  std::array<uint8_t, lcm::kRigKeyBytes> bytes{};
  for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = static_cast<uint8_t>(fill + i);
  return RigKey::from_bytes(bytes);
}

constexpr int64_t kSkewUs = 2'000'000;
constexpr int64_t kNow = 1'700'000'000'000'000;

std::vector<uint8_t> signed_message(const MessageAuth& auth, const std::string& channel,
                                    std::vector<uint8_t> payload, int64_t utime) {
  const size_t n = payload.size();
  payload.resize(n + kSignatureBytes);
  auth.sign(channel, payload.data(), n, utime, payload.data() + n);
  return payload;
}

uint64_t dropped(const MessageAuth& auth, AuthDrop reason) {
  return auth.counters().dropped[static_cast<size_t>(reason)];
}

TEST(MessageAuth, WhatIsSignedWithTheKeyPassesOnceAndNothingElse) {
  MessageAuth signer(key_of(1), kSkewUs);
  MessageAuth receiver(key_of(1), kSkewUs);
  const std::vector<uint8_t> payload = {1, 2, 3, 4, 5, 6, 7, 8, 9};
  const auto good = signed_message(signer, "DEPTHFUSE_COMMAND", payload, kNow);

  auto v = receiver.verify("DEPTHFUSE_COMMAND", good.data(), good.size(), kNow + 1000);
  ASSERT_TRUE(v.ok);
  EXPECT_EQ(v.payload_size, payload.size());
  EXPECT_EQ(receiver.counters().verified, 1u);

  // The same bytes again: a replay.
  v = receiver.verify("DEPTHFUSE_COMMAND", good.data(), good.size(), kNow + 2000);
  EXPECT_FALSE(v.ok);
  EXPECT_EQ(v.reason, AuthDrop::kReplayed);

  // Unsigned: the bare payload, and one too short to hold a signature.
  EXPECT_EQ(receiver.verify("DEPTHFUSE_COMMAND", payload.data(), payload.size(), kNow).reason,
            AuthDrop::kUnsigned);
  EXPECT_EQ(receiver.verify("DEPTHFUSE_COMMAND", nullptr, 0, kNow).reason, AuthDrop::kUnsigned);

  // Another key; any byte altered (payload, time, tag); another channel.
  MessageAuth stranger(key_of(2), kSkewUs);
  const auto foreign = signed_message(stranger, "DEPTHFUSE_COMMAND", payload, kNow);
  EXPECT_EQ(receiver.verify("DEPTHFUSE_COMMAND", foreign.data(), foreign.size(), kNow).reason,
            AuthDrop::kBadSignature);
  for (size_t i : {size_t{0}, payload.size() + 5, good.size() - 1}) {
    auto altered = signed_message(signer, "DEPTHFUSE_COMMAND", payload, kNow + 1);
    altered[i] ^= 0x01;
    EXPECT_EQ(receiver.verify("DEPTHFUSE_COMMAND", altered.data(), altered.size(), kNow).reason,
              AuthDrop::kBadSignature)
        << "byte " << i;
  }
  const auto fresh = signed_message(signer, "DEPTHFUSE_COMMAND", payload, kNow + 7);
  EXPECT_EQ(receiver.verify("DEPTHFUSE_DEPTH", fresh.data(), fresh.size(), kNow).reason,
            AuthDrop::kBadSignature);

  // Signed too long ago, or in the future.
  const auto old = signed_message(signer, "DEPTHFUSE_COMMAND", payload, kNow - kSkewUs - 1);
  EXPECT_EQ(receiver.verify("DEPTHFUSE_COMMAND", old.data(), old.size(), kNow).reason,
            AuthDrop::kStale);
  const auto ahead = signed_message(signer, "DEPTHFUSE_COMMAND", payload, kNow + kSkewUs + 1);
  EXPECT_EQ(receiver.verify("DEPTHFUSE_COMMAND", ahead.data(), ahead.size(), kNow).reason,
            AuthDrop::kStale);

  EXPECT_EQ(receiver.counters().verified, 1u);
  EXPECT_EQ(dropped(receiver, AuthDrop::kReplayed), 1u);
  EXPECT_EQ(dropped(receiver, AuthDrop::kUnsigned), 2u);
  EXPECT_EQ(dropped(receiver, AuthDrop::kBadSignature), 5u);
  EXPECT_EQ(dropped(receiver, AuthDrop::kStale), 2u);
}

TEST(MessageAuth, ATagIsForgottenOnlyOnceAReplayOfItWouldBeStale) {
  MessageAuth auth(key_of(3), kSkewUs);
  const auto msg = signed_message(auth, "C", {42}, kNow);
  ASSERT_TRUE(auth.verify("C", msg.data(), msg.size(), kNow).ok);
  // Within the window the replay is caught by the cache; after it, by its time.
  EXPECT_EQ(auth.verify("C", msg.data(), msg.size(), kNow + kSkewUs).reason, AuthDrop::kReplayed);
  EXPECT_EQ(auth.verify("C", msg.data(), msg.size(), kNow + 3 * kSkewUs).reason, AuthDrop::kStale);
}

TEST(MessageAuth, UnsignedPayloadSizeCutsOnlyATrailer) {
  MessageAuth auth(key_of(4), kSkewUs);
  const std::vector<uint8_t> payload(100, 7);
  const auto msg = signed_message(auth, "C", payload, kNow);
  EXPECT_EQ(lcm::unsigned_payload_size(msg.data(), msg.size()), payload.size());
  EXPECT_EQ(lcm::unsigned_payload_size(payload.data(), payload.size()), payload.size());
  EXPECT_EQ(lcm::unsigned_payload_size(payload.data(), 3), 3u);
}

TEST(RigKey, LoadsAKeyFileAndNamesWhatIsWrongWithABadOne) {
  const std::string dir = testing::temp_dir("rigkey");
  auto write = [&](const std::string& name, const std::string& text, mode_t mode) {
    const std::string path = dir + "/" + name;
    std::ofstream(path) << text;
    ::chmod(path.c_str(), mode);
    return path;
  };
  auto refusal = [](const Result<RigKey>& r) { return r.is_ok() ? "" : r.status().message(); };
  std::string hex;
  for (int i = 0; i < 32; ++i) hex += "a" + std::string(1, "0123456789abcdef"[i % 16]);
  auto good = RigKey::load(write("good", "  " + hex + "\n", 0640));
  ASSERT_TRUE(good.is_ok()) << good.status().to_string();
  EXPECT_EQ(good->bytes()[0], 0xa0);
  EXPECT_EQ(good->bytes()[31], 0xaf);
  EXPECT_EQ(good->fingerprint().size(), 16u);
  EXPECT_NE(good->fingerprint(), key_of(0).fingerprint());

  // Missing: not_found, with the command that makes one.
  auto missing = RigKey::load(dir + "/none");
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
  EXPECT_NE(refusal(missing).find("make one with: (umask 027; od"), std::string::npos)
      << refusal(missing);
  // Others may read or change it, or its group may change it: refused, with the fix.
  for (const auto& [mode, why] : std::vector<std::pair<mode_t, std::string>>{
           {0644, "readable by every user"}, {0602, "writable by every user"},
           {0660, "writable by its group"}}) {
    const std::string path = write("loose", hex, mode);
    EXPECT_EQ(refusal(RigKey::load(path)),
              "rig key " + path + " is " + why + "; restrict it with 'chmod 640 " + path + "'");
  }
  // Not 64 hex digits.
  for (const std::string& bad : {hex.substr(1), hex + "a", hex.substr(2) + "zz", std::string()}) {
    auto r = RigKey::load(write("bad", bad, 0600));
    EXPECT_NE(refusal(r).find("64 hexadecimal digits"), std::string::npos) << bad << ": " << refusal(r);
  }
  // No secret: all zeros, or any byte repeated.
  for (const std::string& weak : {std::string(64, '0'), std::string(64, 'a'), std::string(64, '3')}) {
    auto r = RigKey::load(write("weak", weak, 0600));
    EXPECT_NE(refusal(r).find("is one byte repeated (" + weak.substr(0, 2) + "), no secret"),
              std::string::npos)
        << refusal(r);
  }
  // Not a regular file: refused before it is opened (a FIFO would block the open).
  const std::string fifo = dir + "/fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_EQ(refusal(RigKey::load(fifo)), "rig key " + fifo + " is a FIFO, not a regular file");
  EXPECT_EQ(refusal(RigKey::load(dir)), "rig key " + dir + " is a directory, not a regular file");
}

// A transport on `url` that verifies with `key` when one is given.
auto open_transport(const std::string& url, std::optional<RigKey> key) {
  auto t = lcm::LcmTransport::open(url);
  EXPECT_TRUE(t.is_ok()) << t.status().to_string();
  if (key) (*t)->authenticate(*key, kSkewUs);
  return std::move(t).value();
}

// Over real LCM: a keyed receiver hears a keyed sender and drops, by reason, an unsigned sender
// and one with another key; a receiver without a key reads signed messages too.
TEST(MessageAuth, OverLcmOnlyTheRigsSignedMessagesReachTheHandlers) {
  const std::string url = testing::test_url();
  testing::require_multicast_route(url);
  auto open = [&](std::optional<RigKey> key) { return open_transport(url, key); };
  auto receiver = open(key_of(5));
  auto keyless_receiver = open(std::nullopt);
  auto rig = open(key_of(5));
  auto stranger = open(key_of(6));
  auto open_sender = open(std::nullopt);

  std::vector<std::string> heard;
  std::vector<size_t> sizes;
  receiver->subscribe("AUTH_TEST", [&](const std::string&, const uint8_t* d, size_t n, int64_t) {
    heard.emplace_back(reinterpret_cast<const char*>(d), n);
  });
  std::vector<std::string> heard_keyless;
  keyless_receiver->subscribe("AUTH_TEST", [&](const std::string&, const uint8_t* d, size_t n,
                                                int64_t) {
    heard_keyless.emplace_back(reinterpret_cast<const char*>(d), n);
  });
  const std::string big(200'000, 'x');  // fragmented
  for (const auto& [sender, text] :
       std::vector<std::pair<lcm::LcmTransport*, std::string>>{
           {stranger.get(), "stranger"}, {open_sender.get(), "open"}, {rig.get(), "rig"},
           {rig.get(), big}}) {
    ASSERT_TRUE(sender->publish("AUTH_TEST", text.data(), text.size()).is_ok());
  }
  testing::eventually([&] {
    for (auto* t : {receiver.get(), keyless_receiver.get()}) {
      for (auto r = t->handle(10); r.is_ok() && *r; r = t->handle(10)) {
      }
    }
    return heard.size() >= 2 && heard_keyless.size() >= 4;
  }, std::chrono::seconds(5));
  EXPECT_EQ(heard, (std::vector<std::string>{"rig", big}));
  EXPECT_EQ(heard_keyless, (std::vector<std::string>{"stranger", "open", "rig", big}));
  const auto counters = receiver->receive_counters();
  EXPECT_EQ(counters.auth.verified, 2u);
  EXPECT_EQ(counters.auth.dropped[static_cast<size_t>(AuthDrop::kUnsigned)], 1u);
  EXPECT_EQ(counters.auth.dropped[static_cast<size_t>(AuthDrop::kBadSignature)], 1u);
}

// A message on a channel the receiver does not subscribe to is not verified at all (no HMAC for
// what nobody here reads): whoever signed it, it is only counted as unsubscribed, on udpm (where
// the reassembler leaves it out) as through liblcm's receiver (memq).
TEST(MessageAuth, MessagesOnUnsubscribedChannelsAreCountedNotVerified) {
  for (const bool udpm : {true, false}) {
    const std::string url = udpm ? testing::test_url() : "memq://";
    if (udpm) testing::require_multicast_route(url);
    auto open = [&](std::optional<RigKey> key) { return open_transport(url, key); };
    auto receiver = open(key_of(5));
    // memq delivers within one lcm_t: there the receiver sends everything itself.
    auto rig = udpm ? open(key_of(5)) : nullptr;
    auto stranger = udpm ? open(key_of(6)) : nullptr;
    lcm::LcmTransport* rig_sender = udpm ? rig.get() : receiver.get();
    std::vector<std::string> heard;
    receiver->subscribe("AUTH_WANTED", [&](const std::string& channel, const uint8_t* d,
                                           size_t n, int64_t) {
      heard.push_back(channel + ":" + std::string(reinterpret_cast<const char*>(d), n));
    });
    const std::string big(200'000, 'x');  // fragmented on udpm
    std::vector<std::pair<lcm::LcmTransport*, std::string>> sends{{rig_sender, "rig"},
                                                                  {rig_sender, big}};
    if (stranger) sends.emplace_back(stranger.get(), "stranger");
    for (const auto& [sender, text] : sends)
      ASSERT_TRUE(sender->publish("AUTH_OTHER", text.data(), text.size()).is_ok());
    ASSERT_TRUE(rig_sender->publish("AUTH_WANTED", "yes", 3).is_ok());
    testing::eventually([&] {
      for (auto r = receiver->handle(10); r.is_ok() && *r; r = receiver->handle(10)) {
      }
      return !heard.empty() && receiver->receive_counters().unsubscribed >= sends.size();
    }, std::chrono::seconds(5));
    EXPECT_EQ(heard, (std::vector<std::string>{"AUTH_WANTED:yes"})) << udpm;
    const auto counters = receiver->receive_counters();
    EXPECT_EQ(counters.unsubscribed, sends.size()) << udpm;
    EXPECT_EQ(counters.auth.verified, 1u) << udpm;
    EXPECT_EQ(counters.auth.dropped_total(), 0u) << udpm;
    EXPECT_EQ(counters.udpm.dropped_total(), 0u) << udpm;
  }
}

// Other LCM clients still read what a rig signs: lcm-gen's decoders stop at the end of the type.
TEST(MessageAuth, PythonBindingsReadASignedMessage) {
  depthfuse::heartbeat_t hb{};
  hb.protocol_version = depthfuse::heartbeat_t::PROTOCOL_VERSION;
  hb.name = "signed";
  hb.num_counters = 0;
  MessageAuth auth(key_of(7), kSkewUs);
  const auto msg = signed_message(auth, "DEPTHFUSE_HEARTBEAT", lcm::encode_message(hb), kNow);
  std::string hex;
  for (uint8_t b : msg) {
    char two[3];
    std::snprintf(two, sizeof two, "%02x", b);
    hex += two;
  }
  std::string out;
  const int rc = testing::run_command(
      {DEPTHFUSE_PYTHON3, "-c",
       "import sys; sys.path.insert(0, sys.argv[1]); import depthfuse; "
       "print(depthfuse.heartbeat_t.decode(bytes.fromhex(sys.argv[2])).name)",
       DEPTHFUSE_PYTHON_DIR, hex},
      testing::temp_dir("python-signed") + "/python.log", &out);
  ASSERT_EQ(rc, 0) << out;
  EXPECT_EQ(out, "signed\n");
}

}  // namespace
}  // namespace depthfuse
