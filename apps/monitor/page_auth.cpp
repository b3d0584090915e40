// Checking the page's signed commands (see page_auth.hpp).
#include "page_auth.hpp"

#include <sodium.h>

#include <cstdio>
#include <cstring>
#include <vector>

namespace depthfuse::monitor {

lcm::MessageAuth::Verdict PageCommandAuth::verify(std::string_view body, const char* signature_hex,
                                                  int64_t now_utime) {
  // The body and the trailer, as MessageAuth takes a signed message. A header that is not a
  // trailer in hex leaves the body alone: unsigned.
  std::vector<uint8_t> message(body.size() + lcm::kSignatureBytes);
  std::memcpy(message.data(), body.data(), body.size());
  size_t size = body.size(), trailer_bytes = 0;
  if (signature_hex && std::strlen(signature_hex) == kSignatureHexDigits &&
      sodium_hex2bin(message.data() + body.size(), lcm::kSignatureBytes, signature_hex,
                     kSignatureHexDigits, nullptr, &trailer_bytes, nullptr) == 0 &&
      trailer_bytes == lcm::kSignatureBytes)
    size += lcm::kSignatureBytes;
  std::lock_guard<std::mutex> lock(mutex_);
  const auto verdict = auth_.verify(kPageCommandChannel, message.data(), size, now_utime);
  // A command that verifies means the operator has the right key now: the status stops naming the
  // old refusal (the counters keep the history).
  last_refusal_ = verdict.ok ? std::string() : refusal_text(verdict.reason, auth_.max_skew_us());
  return verdict;
}

lcm::AuthCounters PageCommandAuth::counters() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return auth_.counters();
}

std::string PageCommandAuth::last_refusal() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return last_refusal_;
}

std::string refusal_text(lcm::AuthDrop reason, int64_t max_skew_us) {
  std::string why;
  switch (reason) {
    case lcm::AuthDrop::kUnsigned:
      why = "not signed; this monitor has a rig key, so the page needs it too";
      break;
    case lcm::AuthDrop::kBadSignature:
      why = "the signature does not match the rig key (another key, or the request was altered)";
      break;
    case lcm::AuthDrop::kStale:
    {
      char skew[32];
      std::snprintf(skew, sizeof skew, "%g", static_cast<double>(max_skew_us) * 1e-6);
      why = std::string("signed more than ") + skew +
            " s from the monitor's clock (an old request sent again?)";
      break;
    }
    case lcm::AuthDrop::kReplayed:
      why = "received before (a request sent again)";
      break;
    case lcm::AuthDrop::kCount:
      break;
  }
  return std::string("page command refused (") + lcm::to_string(reason) + "): " + why;
}

}  // namespace depthfuse::monitor
