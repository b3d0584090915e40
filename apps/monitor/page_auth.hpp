// The operator token on the page's commands. With a rig key, the page signs every command as every
// LCM message is signed (lcm::MessageAuth, message_auth.hpp), over the request's body on the
// pseudo-channel kPageCommandChannel, and sends the signature trailer ("DFS1" | utime | tag) as 88
// hexadecimal digits in the X-Depthfuse-Signature header; the monitor checks it here before it
// queues the command, then signs the command_t it publishes with the same key. The operator types
// the key into the page, which keeps it in the tab (sessionStorage): it never crosses the network.
// A command unsigned, signed with another key or altered, signed too long ago or in the future
// (the page takes its time from the monitor), or received before, is refused and counted.
#pragma once

#include <cstdint>
#include <mutex>
#include <string>
#include <string_view>

#include "depthfuse/lcm/message_auth.hpp"

namespace depthfuse::monitor {

// Never an LCM channel: signatures of the page's commands cannot pass for LCM messages.
constexpr const char* kPageCommandChannel = "DEPTHFUSE_PAGE_COMMAND";
constexpr size_t kSignatureHexDigits = 2 * lcm::kSignatureBytes;

class PageCommandAuth {
 public:
  PageCommandAuth(const lcm::RigKey& key, int64_t max_skew_us) : auth_(key, max_skew_us) {}

  // Any web server thread. `body` as received; `signature_hex` the header's value (null when the
  // request has none). Counts the verdict.
  lcm::MessageAuth::Verdict verify(std::string_view body, const char* signature_hex,
                                   int64_t now_utime);

  int64_t max_skew_us() const { return auth_.max_skew_us(); }
  lcm::AuthCounters counters() const;
  // "page command refused (bad_signature): ..." while the last command was refused; empty once
  // one verifies.
  std::string last_refusal() const;

 private:
  mutable std::mutex mutex_;  // MessageAuth's replay cache is not thread-safe
  lcm::MessageAuth auth_;
  std::string last_refusal_;
};

// Why a command was refused, for the page and the log.
std::string refusal_text(lcm::AuthDrop reason, int64_t max_skew_us);

}  // namespace depthfuse::monitor
