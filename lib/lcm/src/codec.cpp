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
  } else if (delta > restart_gap_) {
    o.verdict = Verdict::kRestart;
  } else if (delta > 1) {
    o.verdict = Verdict::kGap;
    o.lost = delta - 1;
    before_jump_ = last_;
    jump_to_ = sequence;
    jump_lost_ = o.lost;
  } else if (-delta > restart_gap_) {
    o.verdict = Verdict::kRestart;
  } else {
    // Late or repeated: the newest sequence stays the reference, unless the frames behind it keep
    // coming one after the other.
    behind_run_ = behind_run_ > 0 && sequence == behind_last_ + 1 ? behind_run_ + 1 : 1;
    if (behind_run_ == 1) behind_first_ = sequence;
    behind_last_ = sequence;
    if (behind_run_ < kResyncAfter) {
      o.verdict = Verdict::kOutOfOrder;
      return o;
    }
    o.verdict = Verdict::kResync;
    // A run inside the last jump, with nothing in order since: the stream went on from before the
    // jump, and what lies between was lost, not what the jump said.
    if (last_ == jump_to_ && behind_first_ > before_jump_)
      o.lost = (behind_first_ - before_jump_ - 1) - jump_lost_;
  }
  behind_run_ = 0;
  last_ = sequence;
  return o;
}

}  // namespace depthfuse::lcm
