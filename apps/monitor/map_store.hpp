// The monitor's copy of the map preview (map_delta_t from the fusion daemon), kept for the pages it
// serves: the newest decimated copy of every chunk, packed once for the browser, the pose and the
// trajectory, which a loop closure's correction (graph_correction_t) moves. Chunks carry a
// version, so that a page that joined late gets everything and a page that is up to date gets only
// what changed. Thread-safe: the LCM thread writes, the web server's threads read.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <tuple>
#include <vector>

#include "depthfuse/graph_correction_t.hpp"
#include "depthfuse/map_delta_t.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse::monitor {

class MapStore {
 public:
  // How much of the map the monitor keeps for pages: beyond it, the oldest chunks are dropped.
  explicit MapStore(size_t max_bytes = 256u << 20) : max_bytes_(max_bytes) {}

  enum class Accepted { kOk, kMalformed, kOtherScan };
  // The LCM thread. Checks the chunks' array sizes (a bad chunk makes the message malformed; the
  // rest of a good message is kept). *want_snapshot turns true when the monitor missed deltas or
  // sees a new sender or scan: it should ask for a snapshot.
  Accepted apply(const depthfuse::map_delta_t& msg, bool* want_snapshot);
  // The LCM thread. A correction of the scan (and fusion daemon) whose map this is moves every
  // kept position, and the last pose, by the motion of the keyframe its frame belongs to
  // (keyframe_motions.hpp); pages then get the whole path again and a note of it. One of another
  // scan or sender is kOtherScan, a broken one kMalformed (*problem says why): neither changes
  // anything.
  Accepted apply(const depthfuse::graph_correction_t& msg, Status* problem);

  // What a page has seen: the map's epoch (a new scan or sender starts another), the newest
  // chunk version, trajectory length (of the path as last corrected) and pose it has, and the
  // corrections it was told of.
  struct Cursor {
    int64_t epoch = -1;
    int64_t version = 0;
    size_t trajectory = 0;
    int64_t pose_version = 0;
    int64_t path_version = 0;
    int64_t correction = 0;
  };
  // Fills `out` with what the page behind `cursor` lacks, at most about max_bytes of chunks:
  // text messages (JSON: reset, pose, trajectory, correction) in *text, packed chunks in *chunks
  // (binary frame layout in docs/operator-view.md). Advances the cursor.
  void changes(Cursor* cursor, size_t max_bytes, std::vector<std::string>* text,
               std::vector<std::shared_ptr<const std::vector<uint8_t>>>* chunks) const;

  size_t chunk_count() const;
  size_t point_count() const;

 private:
  struct Entry {
    int64_t version = 0;
    std::shared_ptr<const std::vector<uint8_t>> packed;
    size_t points = 0;
  };
  using Key = std::tuple<int32_t, int32_t, int32_t>;

  std::string pose_json() const;

  size_t max_bytes_;
  mutable std::mutex mutex_;
  int64_t epoch_ = 0;
  std::string sender_, scan_id_;
  int64_t last_sequence_ = 0;
  int64_t version_ = 0;
  size_t bytes_ = 0, points_ = 0;
  std::map<Key, Entry> chunks_;
  std::map<int64_t, Key> by_version_;  // each chunk once, under its newest version
  std::vector<float> trajectory_;      // x y z per pose, in the order received
  std::vector<int64_t> trajectory_sequence_;  // per pose its frame's sequence, for corrections
  int64_t path_version_ = 0;           // corrections that moved the path: pages get it anew
  int64_t correction_ = 0;             // corrections applied to this map
  std::string correction_json_;        // the last one as the page's note
  depthfuse::map_delta_t last_;        // its header (chunks dropped): pose, state, figures
  bool have_last_ = false;
  std::string pose_json_;              // last_ as the page's pose message
  int64_t pose_version_ = 0;           // counts the deltas, so that a page gets each pose once
};

}  // namespace depthfuse::monitor
