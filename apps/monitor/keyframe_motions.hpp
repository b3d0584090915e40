// A loop closure's correction (graph_correction_t, DEPTHFUSE_GRAPH) checked and made ready to move
// the poses the fusion daemon published: a pose moves with the keyframe its frame belongs to, the
// last keyframe whose first frame's sequence is at most the pose's; before the first, it stays.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "depthfuse/graph_correction_t.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::monitor {

class KeyframeMotions {
 public:
  // Beyond any scan (at the fusion daemon's keyframe spacing, some 10 km of camera path): a larger
  // correction is refused, and so is a message that could only hold one, before it is decoded.
  static constexpr int32_t kMaxKeyframes = 65536;
  static constexpr size_t kMaxEncodedBytes = static_cast<size_t>(kMaxKeyframes) * 64 + 4096;
  // No keyframe of a room moves by a kilometre: such a motion is a broken message.
  static constexpr double kMaxTranslationM = 1000.0;

  // An error names what is wrong with the message: its array sizes, a motion that is not finite
  // or not a rotation, too many keyframes.
  static Result<KeyframeMotions> from_message(const depthfuse::graph_correction_t& msg);

  // The motion (new T_world_cam = motion * old) of the frame `sequence`, null when it comes
  // before every keyframe. O(log keyframes).
  const Pose* of(int64_t sequence) const;
  size_t size() const { return motion_.size(); }

 private:
  // The keyframes' first sequences in ascending order, and for each entry the largest keyframe
  // index among it and those before it: so "the last keyframe (in the message's order) whose
  // first sequence is at most s" holds even if the sequences are not in order (a capture
  // restart renumbers frames).
  std::vector<int64_t> sorted_sequence_;
  std::vector<size_t> last_keyframe_;
  std::vector<Pose> motion_;
};

}  // namespace depthfuse::monitor
