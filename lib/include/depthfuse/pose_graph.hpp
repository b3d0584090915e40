// The pose graph of a scan's keyframes: nodes are keyframe poses, edges are relative poses measured
// between them (odometry from tracking, loops from closures), each with the information of its
// measurement. optimise_pose_graph finds the poses that best agree with all edges, a wrong loop
// closure being first down-weighted by a robust loss and then rejected by its chi2.
//
// A pure function: no threads, no state kept between calls; callers run it on a thread of their
// own. The solver (Ceres) stays inside its .cpp.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse {

// 6-vector order everywhere: rotation (rx, ry, rz; rad) then translation (tx, ty, tz; m).
using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

struct PoseGraphEdge {
  enum class Kind { kOdometry, kLoop };
  uint32_t from = 0, to = 0;  // node indices
  Pose T_from_to;             // the measured pose of `to` in `from`'s frame
  // Information (inverse covariance) of the edge's error
  //   e = Log( T_from_to^-1 * T_world_from^-1 * T_world_to )      (a twist in `to`'s frame,
  // rotation first): a right perturbation of `to`. Log is SE(3)'s: e's translation is V(w)^-1 t,
  // which equals t to first order. Symmetric positive semi-definite: a direction the measurement
  // did not see has (near) zero information and carries no weight.
  Matrix6d information = Matrix6d::Identity();
  Kind kind = Kind::kOdometry;
};

struct PoseGraphOptions {
  // Loop edges get a Cauchy loss of this scale on their whitened error (sqrt of chi2): the pull of
  // an edge falls off as its error grows past the scale, so a wrong closure barely bends the map
  // before it is rejected (Huber's pull never falls below a constant). About the square root of
  // loop_chi2_reject: a right closure keeps most of its weight (3/4 at the chi2 of 6 it has on
  // average), one far outside the gate very little. Where drift puts loops beyond the scale, the
  // graph is first solved by least squares, so that a right closure is not taken for a wrong one.
  double loop_loss_scale = 4.0;
  // After optimising, a loop edge whose chi2 (e^T I e) is above this is rejected and the graph is
  // optimised again without it (a few rounds at most). 16.8 is chi2 with 6 degrees of freedom at
  // 99 %: a right closure whose information is honest is rejected once in a hundred.
  double loop_chi2_reject = 16.8;
  int max_iterations = 50;                   // per solve (each round has one or two)
  std::vector<uint32_t> fixed_nodes = {0};   // the gauge: at least one
  // Nodes before this one stay where they are, as fixed nodes do, and the edges between two of
  // them are left out: they cost the same at any solution. Solving the newest nodes only keeps a
  // solve's cost with the window's size, not the graph's. 0: every node but the fixed ones free.
  uint32_t first_free_node = 0;
};

struct PoseGraphResult {
  std::vector<Pose> T_world_node;   // optimised, one per node
  std::vector<bool> edge_used;      // false: a loop edge rejected
  std::vector<double> edge_chi2;    // each edge's chi2 at the solution (rejected ones too)
  // Half the sum of the (loop edges: robustified) chi2 of the edges used: at the initial poses
  // with every edge, and at the solution with the edges kept.
  double initial_cost = 0, final_cost = 0;
  int iterations = 0;               // over all rounds
  size_t loops_rejected = 0;
};

// Errors (invalid argument) name the edge or node at fault: an edge naming a missing node or
// joining a node to itself, a pose or information that is not finite, a pose whose rotation is not
// one, an information that is not symmetric positive semi-definite, no fixed node or one out of
// range, an option out of its range. Nodes that no edge reaches keep their initial pose.
Result<PoseGraphResult> optimise_pose_graph(const std::vector<Pose>& T_world_node_initial,
                                            const std::vector<PoseGraphEdge>& edges,
                                            const PoseGraphOptions& options = {});

}  // namespace depthfuse
