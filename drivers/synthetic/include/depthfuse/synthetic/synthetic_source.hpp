// The synthetic driver as a FrameSource: streams a SyntheticSequence, every frame carrying the
// perturbed pose as T_world_cam_hint (the true pose when the pose noise is 0), unless the
// configuration's pose_hints is off.
#pragma once

#include <memory>
#include <optional>
#include <string>

#include "depthfuse/app_config.hpp"
#include "depthfuse/frame_source.hpp"
#include "depthfuse/synthetic/synthetic_sequence.hpp"

namespace depthfuse {
namespace synthetic {

class SyntheticSource : public FrameSource {
 public:
  explicit SyntheticSource(SyntheticSequence sequence, bool with_noise = true);

  Result<Frame> next() override;
  std::string describe() const override;  // "synthetic:corner (60 frames, seed 1)"
  std::optional<double> nominal_rate_hz() const override { return sequence_.config().rate_hz; }
  std::optional<size_t> frame_count() const override { return sequence_.size() - first_frame(); }
  Status rewind() override;

  const SyntheticSequence& sequence() const { return sequence_; }

 private:
  size_t first_frame() const { return static_cast<size_t>(sequence_.config().first_frame); }

  SyntheticSequence sequence_;
  bool with_noise_ = true;
  size_t next_index_ = 0;
};

// Parses a scene ("corner", "room", "rooms", "furnished", "plain"), optionally followed by
// "?frames=N&seed=S&pose_noise_m=X&pose_noise_deg=Y&rate_hz=R&noise=0|1&hints=0|1&first=F" into
// `base` (whose other fields are kept; the lap walks' frames default to default_frames()). hints=0:
// no pose hints, as a Kinect. first=F: the stream starts at frame F of the walk (its sequence
// numbers and stamps stay the walk's). Unknown keys and bad numbers are invalid_argument errors
// naming them.
Result<SyntheticConfig> parse_synthetic_spec(const std::string& arg,
                                             const SyntheticConfig& base = SyntheticConfig());

}  // namespace synthetic

// The factory entry point of the driver (see source_factory.hpp): arg as parse_synthetic_spec takes
// it. Intrinsics come from the calibration of serial "synthetic" in `config` when it has one.
Result<std::unique_ptr<FrameSource>> open_synthetic_source(const std::string& arg,
                                                           const AppConfig& config);

}  // namespace depthfuse
