// Decoding raw LCM payloads into depthfuse messages without ever trusting them: a truncated or
// corrupt payload, another LCM type on one of our channels (fingerprint mismatch) and a protocol
// version this build does not know are told apart and counted, never crash the receiver.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <exception>
#include <string>
#include <vector>

namespace depthfuse::lcm {

enum class DecodeResult {
  kOk,
  kMalformed,   // truncated, corrupt, or failing the type's own checks
  kBadVersion,  // our type, but a protocol_version this build does not understand
  kForeign,     // another LCM type on our channel (fingerprint mismatch)
};
const char* to_string(DecodeResult r);

// The first 8 bytes of every LCM message: the type's fingerprint, big-endian. 0 if too short.
uint64_t payload_fingerprint(const void* data, size_t size);

// Decodes `data` as Msg (an lcm-gen type with a protocol_version field and PROTOCOL_VERSION).
template <typename Msg>
DecodeResult decode_message(const void* data, size_t size, Msg* out) {
  if (data == nullptr || size < 8) return DecodeResult::kMalformed;
  if (payload_fingerprint(data, size) != static_cast<uint64_t>(Msg::getHash()))
    return DecodeResult::kForeign;
  if (size > static_cast<size_t>(INT32_MAX)) return DecodeResult::kMalformed;
  try {
    const int used = out->decode(data, 0, static_cast<int>(size));
    if (used < 0) return DecodeResult::kMalformed;
    // Trailing bytes do not belong to any message of ours: someone truncated or glued payloads.
    if (static_cast<size_t>(used) != size) return DecodeResult::kMalformed;
  } catch (const std::exception&) {
    return DecodeResult::kMalformed;
  }
  if (out->protocol_version != Msg::PROTOCOL_VERSION) return DecodeResult::kBadVersion;
  return DecodeResult::kOk;
}

template <typename Msg>
std::vector<uint8_t> encode_message(const Msg& msg) {
  std::vector<uint8_t> buf(static_cast<size_t>(msg.getEncodedSize()));
  msg.encode(buf.data(), 0, static_cast<int>(buf.size()));
  return buf;
}

// Follows a stream's sequence numbers: a jump forward by n means n-1 frames were lost; going back
// (or a repeat) is out of order. A jump back by more than `restart_gap` is taken as the sender
// restarting (e.g. --loop, a new capture process) and resynchronises instead of counting forever;
// so is a jump forward by more than `restart_gap`: a counter of lost frames must not read two
// billion because one frame (a stranger's, or a sender that restarted with another numbering)
// carried the sequence + 2^31. An outage longer than the gap (1000 frames, 33 s at 30 Hz) is then
// counted as a restart too, not as its frames.
// One jump is not trusted either: kResyncAfter frames in a row, each one after the other but
// behind the reference, are the stream, and the reference follows them (kResync). Without that, one
// spoofed frame with the sequence +1000 had the next 1000 real frames rejected as late.
class SequenceTracker {
 public:
  static constexpr int kResyncAfter = 3;
  explicit SequenceTracker(int64_t restart_gap = 1000) : restart_gap_(restart_gap) {}

  enum class Verdict { kFirst, kInOrder, kGap, kOutOfOrder, kRestart, kResync };
  struct Observation {
    Verdict verdict = Verdict::kFirst;
    // Frames missing before this one. On kResync, negative when it takes back the frames a jump
    // had counted as lost but the stream then delivered.
    int64_t lost = 0;
  };
  Observation observe(int64_t sequence);
  void reset() { have_last_ = false; }
  int64_t last() const { return last_; }

 private:
  int64_t restart_gap_;
  bool have_last_ = false;
  int64_t last_ = 0;
  // The last jump forward: the reference before and after it, and the frames it counted as lost.
  int64_t before_jump_ = 0, jump_to_ = -1, jump_lost_ = 0;
  // Frames in a row behind the reference, each one after the other: the first and the last.
  int64_t behind_first_ = 0, behind_last_ = 0;
  int behind_run_ = 0;
};

// What a receiver could not use, by reason. Thread-safe; copied into heartbeats.
struct ReceiveCounters {
  std::atomic<int64_t> received{0};      // decoded and accepted
  std::atomic<int64_t> malformed{0};
  std::atomic<int64_t> bad_version{0};
  std::atomic<int64_t> foreign{0};
  std::atomic<int64_t> lost{0};          // sequence gaps
  std::atomic<int64_t> out_of_order{0};  // sequence went back (or repeated)
  // The sequence jumped by more than the restart gap either way: a sender restarted, or a frame
  // carried a number from elsewhere; never counted as lost frames.
  std::atomic<int64_t> sequence_restarts{0};
  // Frames taken without their pose hint: it lay outside FrameLimits (the workspace) or was not
  // a pose (frame_codec.hpp, DepthFrameNotes).
  std::atomic<int64_t> pose_hints_refused{0};

  void count(DecodeResult r) {
    switch (r) {
      case DecodeResult::kOk: ++received; break;
      case DecodeResult::kMalformed: ++malformed; break;
      case DecodeResult::kBadVersion: ++bad_version; break;
      case DecodeResult::kForeign: ++foreign; break;
    }
  }
  // A frame's place in its stream: its lost frames, out of order, a restart.
  void count(const SequenceTracker::Observation& seen) {
    lost += seen.lost;
    if (seen.verdict == SequenceTracker::Verdict::kOutOfOrder) ++out_of_order;
    if (seen.verdict == SequenceTracker::Verdict::kRestart) ++sequence_restarts;
  }
};

}  // namespace depthfuse::lcm
