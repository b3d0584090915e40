#include "depthfuse/lcm/codec.hpp"

namespace depthfuse::lcm {

const char* to_string(DecodeResult r) {
  switch (r) {
    case DecodeResult::kOk: return "ok";
    case DecodeResult::kMalformed: return "malformed";
    case DecodeResult::kBadVersion: return "unknown protocol version";
    case DecodeResult::kForeign: return "foreign type";
  }
  return "?";
}

uint64_t payload_fingerprint(const void* data, size_t size) {
  if (data == nullptr || size < 8) return 0;
  const auto* b = static_cast<const uint8_t*>(data);
  uint64_t h = 0;
  for (int i = 0; i < 8; ++i) h = (h << 8) | b[i];
  return h;
}

SequenceTracker::Observation SequenceTracker::observe(int64_t sequence) {
  Observation o;
  if (!have_last_) {
    have_last_ = true;
    last_ = sequence;
    o.verdict = Verdict::kFirst;
    return o;
  }
  const int64_t delta = sequence - last_;
  if (delta == 1) {
    o.verdict = Verdict::kInOrder;
  } else if (delta > 1) {
    o.verdict = Verdict::kGap;
    o.lost = delta - 1;
  } else if (-delta > restart_gap_) {
    o.verdict = Verdict::kRestart;
  } else {
    // Late or repeated: the newest sequence stays the reference.
    o.verdict = Verdict::kOutOfOrder;
    return o;
  }
  last_ = sequence;
  return o;
}

}  // namespace depthfuse::lcm
