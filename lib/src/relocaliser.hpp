// Relocalisation of a lost camera: keyframes kept in memory while tracking, searched when tracking
// is lost. PCL's feature and registration headers stay in relocaliser.cpp (about 1 GB and 20 s to
// compile a translation unit that includes them).
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <vector>

#include "depthfuse/config.hpp"
#include "depthfuse/measurement.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse {

struct KeyframeCloud;

// The place search of the loop closer, with the relocaliser's machinery: FPFH features of both
// keyframes' points and PCL's prerejective sample consensus (config's sac_* settings). The pose of
// `source` in `target`'s frame, or nothing. `seed` makes a run repeatable.
std::optional<Pose> align_by_features(const KeyframeCloud& source, const KeyframeCloud& target,
                                      const RelocalisationConfig& config, unsigned seed);

class Relocaliser {
 public:
  explicit Relocaliser(const RelocalisationConfig& config);
  ~Relocaliser();
  Relocaliser(const Relocaliser&) = delete;
  Relocaliser& operator=(const Relocaliser&) = delete;

  // After a frame is tracked and fused at T_world_cam: keeps it as a keyframe (a thumbnail of its
  // depth and its downsampled points with normals, in its camera frame) when no keyframe is within
  // keyframe_spacing_m and keyframe_spacing_deg of it. Past max_keyframes the keyframe closest to
  // another one goes. Also ends a search: the camera is tracked again.
  void frame_tracked(const MeasurementImage& m, const Pose& T_world_cam, uint32_t frame_id);

  // Keyframes from stored frames (a resumed scan), walking back from the newest stored one:
  //  - wants: whether a frame at T_world_cam would become a keyframe by frame_tracked()'s spacing
  //    rule and there is room (checked on the pose alone, before the frame is decoded);
  //  - add_older_keyframe: makes it one, ahead of every keyframe held (it is older than they are,
  //    and the rule that drops a keyframe when full drops the older of the two nearest). True
  //    when kept (false: too few points, near one held, or full).
  bool wants(const Pose& T_world_cam) const;
  bool add_older_keyframe(const MeasurementImage& m, const Pose& T_world_cam, uint32_t frame_id);
  // A loop closure moved the frames: each keyframe to moved(its frame id, its pose).
  void move_keyframes(const std::function<Pose(uint32_t frame_id, const Pose&)>& moved);

  // For a lost frame: where the camera is, or nothing. At most candidates_per_frame keyframes are
  // tried, on every every_n_lost_frames-th lost frame in a row. Keyframes are ranked by how alike
  // their depth thumbnails are to this frame's; the best is tried on every other attempt, the
  // others in turn. For a keyframe, two candidate poses go to `verify` (tracking against the map;
  // the pose it tracked to, or nothing): the keyframe's own, then the keyframe's pose times the
  // FPFH sample-consensus alignment of the frame's points to the keyframe's. The first place
  // verified is returned only if none of up to ambiguity_rivals other keyframes, the most alike
  // first, is verified too more than ambiguity_m from it; `*ambiguous` says it was refused so.
  using Verify = std::function<std::optional<Pose>(const Pose& candidate)>;
  std::optional<Pose> search(const MeasurementImage& m, const Verify& verify, bool* ambiguous);

  void clear();
  size_t keyframe_count() const { return keyframes_.size(); }
  // What the keyframes hold at most (max_keyframes full ones, features computed), and the search
  // of a frame of `pixels` (its points before the voxel grid).
  static size_t memory_bound_bytes(const RelocalisationConfig& config, size_t pixels);

 private:
  struct Keyframe;
  std::unique_ptr<Keyframe> make_keyframe(const MeasurementImage& m, const Pose& T_world_cam,
                                          uint32_t frame_id) const;
  // The frame's points and features for sample consensus, made once per search.
  struct FrameCloud;
  // Where the frame is by keyframe k (its pose, then sample consensus), as verified, or nothing.
  std::optional<Pose> try_keyframe(Keyframe& k, const MeasurementImage& m, FrameCloud* frame,
                                   const Verify& verify, unsigned seed);
  RelocalisationConfig config_;
  std::vector<std::unique_ptr<Keyframe>> keyframes_;
  int lost_frames_ = 0;  // in a row, since the last tracked frame
};

}  // namespace depthfuse
