// Internal: the loop closer. For every new keyframe of a ScanGraph it looks for an older keyframe
// of the same place (near where the graph puts the new one, within the odometry's uncertainty, or
// found by the place search), verifies each candidate by ICP of the two keyframes' points, gates
// it by the odometry's uncertainty, and optimises the pose graph (optimise_pose_graph: Ceres, with
// a robust loss that rejects what the rest of the graph contradicts). In the background (the
// fusion daemon: never on the fusion thread) or at once (offline, repeatable).
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "depthfuse/config.hpp"
#include "depthfuse/pose_graph.hpp"
#include "depthfuse/scan_graph.hpp"

namespace depthfuse {

// The graph as it stood when a keyframe was made (the keyframes' clouds are shared, not copied).
struct GraphSnapshot {
  std::vector<GraphKeyframe> keyframes;
  std::vector<PoseGraphEdge> odometry;
  std::vector<Matrix6d> odometry_covariance;
};


class LoopCloser {
 public:
  // background: a thread of its own at a low priority; otherwise submit() does the work.
  LoopCloser(const LoopClosureConfig& config, const RelocalisationConfig& place_search,
             bool background);
  ~LoopCloser();
  LoopCloser(const LoopCloser&) = delete;
  LoopCloser& operator=(const LoopCloser&) = delete;

  // After a new keyframe: the graph as it is. Keyframes not searched yet are searched (when the
  // thread is behind, several at once, newest first).
  void submit(GraphSnapshot snapshot);
  // Before the first submit() of a resumed scan: the loop edges it believed before, and the
  // keyframes it had searched (the next snapshot's older ones are candidates, not searched again).
  void restore(std::vector<PoseGraphEdge> loops, size_t searched);
  // The newest correction found and not yet taken; never waits.
  std::optional<GraphCorrection> take();
  // Waits until everything submitted has been searched (the end of an offline run).
  void wait_idle();
  LoopClosureStats stats() const;
  // Keyframes [0, searched()) have been searched: a keyframe's points are not needed as the new
  // one's any more (ScanGraph::forget_redundant_clouds).
  size_t searched() const;

 private:
  void run();
  // Searches the snapshot's keyframes from `first` on; a correction if a loop was added.
  std::optional<GraphCorrection> process(const GraphSnapshot& s, size_t first);
  // One keyframe's candidates; appends the loop edges believed.
  void search(const GraphSnapshot& s, size_t k, std::vector<PoseGraphEdge>* found);
  // Whether keyframe k sees keyframe i's place: ICP of k's points against i's from T_i_k_initial,
  // then the gate against `path_covariance` (k relative to i by the odometry, in k's frame).
  bool believe(const GraphSnapshot& s, size_t i, size_t k, const Pose& T_i_k_initial,
               const Matrix6d& path_covariance, std::vector<PoseGraphEdge>* found);

  LoopClosureConfig config_;
  RelocalisationConfig place_search_;
  bool background_;
  std::vector<PoseGraphEdge> loops_;  // every loop edge believed and kept by the optimiser
  size_t searched_ = 0;               // keyframes searched so far, or being searched
  size_t done_ = 0;                   // keyframes searched so far (under mutex_)
  mutable std::mutex mutex_;
  std::condition_variable wake_, idle_;
  std::optional<GraphSnapshot> pending_;
  std::optional<GraphCorrection> correction_;
  bool busy_ = false, stop_ = false;
  LoopClosureStats stats_;
  std::thread thread_;
};

}  // namespace depthfuse
