#include "keyframe_motions.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "depthfuse/lcm/frame_codec.hpp"

namespace depthfuse::monitor {

Result<KeyframeMotions> KeyframeMotions::from_message(const depthfuse::graph_correction_t& msg) {
  const int32_t n = msg.num_keyframes;
  if (n < 0 || n > kMaxKeyframes)
    return corrupt("graph correction with " + std::to_string(n) + " keyframes (at most " +
                   std::to_string(kMaxKeyframes) + ")");
  const size_t count = static_cast<size_t>(n);
  if (msg.first_sequence.size() != count || msg.num_translations != 3 * n ||
      msg.motion_translation_m.size() != 3 * count || msg.num_rotations != 4 * n ||
      msg.motion_orientation_wxyz.size() != 4 * count)
    return corrupt("graph correction's arrays do not match its " + std::to_string(n) +
                   " keyframes (num_translations " + std::to_string(msg.num_translations) +
                   ", num_rotations " + std::to_string(msg.num_rotations) + ")");
  if (!std::isfinite(msg.max_translation_m))
    return corrupt("graph correction's max_translation_m is not finite");
  KeyframeMotions out;
  out.motion_.reserve(count);
  for (size_t k = 0; k < count; ++k) {
    auto motion = lcm::pose_from_arrays(&msg.motion_translation_m[3 * k],
                                        &msg.motion_orientation_wxyz[4 * k]);
    if (!motion) return motion.status().with_context("graph correction, keyframe " + std::to_string(k));
    if (!(motion->translation().norm() <= kMaxTranslationM))
      return corrupt("graph correction moves keyframe " + std::to_string(k) + " by more than " +
                     std::to_string(static_cast<int>(kMaxTranslationM)) + " m");
    out.motion_.push_back(*motion);
  }
  std::vector<size_t> order(count);
  std::iota(order.begin(), order.end(), size_t{0});
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
    return msg.first_sequence[a] < msg.first_sequence[b];
  });
  out.sorted_sequence_.reserve(count);
  out.last_keyframe_.reserve(count);
  for (const size_t k : order) {
    out.sorted_sequence_.push_back(msg.first_sequence[k]);
    out.last_keyframe_.push_back(out.last_keyframe_.empty() ? k : std::max(k, out.last_keyframe_.back()));
  }
  return out;
}

const Pose* KeyframeMotions::of(int64_t sequence) const {
  const auto it = std::upper_bound(sorted_sequence_.begin(), sorted_sequence_.end(), sequence);
  if (it == sorted_sequence_.begin()) return nullptr;
  return &motion_[last_keyframe_[static_cast<size_t>(it - sorted_sequence_.begin()) - 1]];
}

}  // namespace depthfuse::monitor
