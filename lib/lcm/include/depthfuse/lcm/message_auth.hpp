// Authenticating every LCM message of a rig with one shared secret, the rig key.
//
// LCM itself is unauthenticated multicast: anyone who can send to the group can publish frames,
// poses, heartbeats and commands. With a rig key, every depthfuse program signs what it publishes
// and drops, unseen by its handlers, whatever is not signed with the same key, signed too long ago
// or in the future, or already received. The operator's commands are authenticated the same way:
// the command's signature is the operator token.
//
// The signature is a trailer after the lcm-gen encoding, so the message types and their
// fingerprints are unchanged and other LCM clients (lcm-spy, lcm-logger, Python, Java) still
// decode the messages; lcm-gen's decoders stop at the end of the type and ignore the trailer.
//
//   payload | "DFS1" | utime (int64, big-endian, the signer's wall clock, microseconds) | tag
//
// tag = HMAC-SHA-512-256(key, channel | NUL | payload | "DFS1" | utime), 32 bytes (libsodium's
// crypto_auth). Covering the channel stops a signed message from being replayed on another
// channel; the time and a cache of recent tags stop it from being replayed later.
//
// What it does not do: hide anything (messages stay readable by anyone on the network), protect
// against a holder of the key, or stop a flood of packets from using up the network and the
// receivers' time (packets are dropped after at most one HMAC, before they are decoded; those on
// channels the receiver does not subscribe to are not verified at all, see LcmTransport).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_set>

#include "depthfuse/status.hpp"

namespace depthfuse::lcm {

constexpr size_t kRigKeyBytes = 32;
constexpr uint32_t kSignatureMagic = 0x44465331;  // "DFS1"
constexpr size_t kSignatureTagBytes = 32;
constexpr size_t kSignatureBytes = 4 + 8 + kSignatureTagBytes;

// The secret of one rig. Its file holds the key as 64 hexadecimal digits (whitespace around them
// is allowed), readable by root and the daemons' group only.
class RigKey {
 public:
  // Reads a key file. Errors name the file, the problem and the fix: missing (not_found),
  // unreadable, not a regular file, not 64 hex digits, readable or writable by every user or
  // writable by its group, one byte repeated (all zeros).
  static Result<RigKey> load(const std::string& path);
  // The shell command that makes a key file at `path`, as the package does.
  static std::string how_to_make(const std::string& path);
  static RigKey from_bytes(const std::array<uint8_t, kRigKeyBytes>& bytes);

  const std::array<uint8_t, kRigKeyBytes>& bytes() const { return bytes_; }
  // A short, non-secret name of the key (hex of a hash of it), so that two hosts can tell whether
  // they hold the same key without showing it.
  std::string fingerprint() const;

 private:
  std::array<uint8_t, kRigKeyBytes> bytes_{};
};

// Why a received message was dropped.
enum class AuthDrop : uint8_t {
  kUnsigned,      // no signature trailer
  kBadSignature,  // a trailer whose tag does not match: another key, or the bytes were altered
  kStale,         // signed further in the past or the future than the allowed clock skew
  kReplayed,      // the same signed message already arrived
  kCount
};
const char* to_string(AuthDrop reason);

struct AuthCounters {
  uint64_t verified = 0;
  std::array<uint64_t, static_cast<size_t>(AuthDrop::kCount)> dropped{};
  uint64_t dropped_total() const;
};

// Signs and verifies with one key. sign() is const and may be called from any thread; verify()
// keeps the replay cache and is called from the receiving thread only.
class MessageAuth {
 public:
  // max_skew_us: how far a message's time may lie from the receiver's clock.
  MessageAuth(const RigKey& key, int64_t max_skew_us);

  // Writes the kSignatureBytes trailer of `payload` on `channel` at `utime` to `trailer`.
  void sign(std::string_view channel, const uint8_t* payload, size_t size, int64_t utime,
            uint8_t* trailer) const;

  // Checks a received message (payload and trailer) at the receiver's time `now_utime`. Returns
  // the payload's size without the trailer, or why it was dropped. Counts either way.
  struct Verdict {
    bool ok = false;
    AuthDrop reason = AuthDrop::kUnsigned;
    size_t payload_size = 0;
  };
  Verdict verify(std::string_view channel, const uint8_t* data, size_t size, int64_t now_utime);

  const AuthCounters& counters() const { return counters_; }
  int64_t max_skew_us() const { return max_skew_us_; }

 private:
  void tag(std::string_view channel, const uint8_t* payload, size_t size, const uint8_t* header,
           uint8_t* out) const;
  bool seen_before(const uint8_t* tag, int64_t now_utime);

  std::array<uint8_t, kRigKeyBytes> key_{};
  int64_t max_skew_us_;
  AuthCounters counters_;
  // Tags of the messages accepted within the last 2 * max_skew (a replay after that is stale),
  // by their first 8 bytes, and in order of arrival to forget them.
  std::unordered_set<uint64_t> recent_;
  std::deque<std::pair<int64_t, uint64_t>> recent_order_;
};

// The payload's size without a signature trailer, if the message has one. For a receiver without
// a key, which cannot check it (a bus without a key is unauthenticated anyway), and for files
// recorded from the bus (lcm-logger logs).
size_t unsigned_payload_size(const uint8_t* data, size_t size);

}  // namespace depthfuse::lcm
