// Replays a session recorded with lcm-logger: depth_frame_t on DEPTHFUSE_DEPTH, with the
// color_frame_t of the same sequence number from DEPTHFUSE_COLOR when there is one.
//   lcmlog:<file>[?depth_channel=NAME&color_channel=NAME]
// The log is indexed when opened; a truncated log ends at its last complete event, corrupt bytes
// are skipped up to the next event marker, and events that do not decode (malformed, foreign
// type, unknown protocol version) are counted and skipped, never fatal.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <unordered_map>
#include <vector>

#include "depthfuse/app_config.hpp"
#include "depthfuse/frame_source.hpp"
#include "depthfuse/lcm/frame_codec.hpp"

namespace depthfuse::lcmlog {

struct LcmLogStats {
  size_t events = 0;             // complete events in the log
  size_t depth_frames = 0;       // usable depth frames
  size_t color_frames = 0;
  size_t malformed = 0;          // failed to decode or failed their checks (limits included)
  std::string first_problem;     // why the first malformed depth frame was refused
  size_t bad_version = 0;
  size_t foreign = 0;            // another type on a depthfuse channel
  size_t corrupt_regions = 0;    // damaged event headers skipped
  bool truncated = false;        // the last event was cut off
  // Frames whose pose hint was left out (outside limits.max_pose_hint_m, or no pose): replayed
  // without it, as the fusion daemon takes them from the bus. And why the first was.
  size_t pose_hints_refused = 0;
  std::string first_pose_hint_refused;
};

class LcmLogSource : public FrameSource {
 public:
  struct Options {
    std::string depth_channel = "DEPTHFUSE_DEPTH";
    std::string color_channel = "DEPTHFUSE_COLOR";
    // Frames beyond them are refused on their header, as the fusion daemon refuses them on the
    // bus; open_lcmlog_source takes fusion_daemon.max_frame_width/height and its
    // workspace_radius_m (a hint beyond it is left out).
    lcm::FrameLimits limits;
  };
  static Result<std::unique_ptr<LcmLogSource>> open(const std::string& path, const Options& options);
  ~LcmLogSource() override;

  Result<Frame> next() override;
  std::string describe() const override;
  std::optional<double> nominal_rate_hz() const override;
  std::optional<size_t> frame_count() const override { return depth_.size(); }
  Status rewind() override {
    next_ = 0;
    return Status::ok();
  }
  // A log replays at the pace lcm-logger received its frames (last_log_utime()).
  int64_t recorded_utime(const Frame&) const override { return last_log_utime(); }
  bool paced_as_recorded() const override { return true; }

  const LcmLogStats& stats() const { return stats_; }
  // Frame i without advancing.
  Result<Frame> load(size_t i);
  // Log time (lcm-logger's receive clock, microseconds) of depth frame i.
  int64_t log_utime(size_t i) const { return depth_[i].log_utime; }
  // Log time of the frame next() returned last (the recorded pace for a replay); 0 before any.
  int64_t last_log_utime() const { return next_ > 0 ? depth_[next_ - 1].log_utime : 0; }

 private:
  struct Event {
    long offset = 0;
    int64_t log_utime = 0;
  };
  LcmLogSource() = default;
  Status index();
  Result<std::vector<uint8_t>> read_payload(long offset);

  std::string path_;
  Options options_;
  void* log_ = nullptr;  // lcm_eventlog_t
  std::vector<Event> depth_;
  std::unordered_map<int64_t, Event> color_by_sequence_;
  LcmLogStats stats_;
  size_t next_ = 0;
};

// The factory's entry point: arg is "<file>[?depth_channel=..&color_channel=..]".
Result<std::unique_ptr<FrameSource>> open_lcmlog_source(const std::string& arg,
                                                        const AppConfig& config);

}  // namespace depthfuse::lcmlog
