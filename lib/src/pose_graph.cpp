// The pose graph's checks, its problem for Ceres, and the rounds that reject wrong loop edges. The
// error of one edge is in pose_graph_error.hpp.
#include "depthfuse/pose_graph.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>

#include <ceres/autodiff_cost_function.h>
#include <ceres/loss_function.h>
#include <ceres/manifold.h>
#include <ceres/problem.h>
#include <ceres/solver.h>
#include <Eigen/Eigenvalues>

#include "depthfuse/pose_delta.hpp"
#include "depthfuse/base/log.hpp"
#include "pose_graph_error.hpp"
#include "solver_log.hpp"

namespace depthfuse {
namespace {

DF_LOG_CATEGORY(PoseGraph)

// Rejecting loops and optimising again: each round drops the loops that its solution disagrees
// with; a graph whose closures are mostly right settles in one or two. The last round's solution
// stands with the loops it used.
constexpr int kMaxRounds = 3;
// Relative tolerances for an information matrix computed in floating point (e.g. summed in float
// by the registration): asymmetry and negative eigenvalues below these are rounding.
constexpr double kSymmetryTolerance = 1e-6;
constexpr double kNegativeEigenvalueTolerance = 1e-6;
// Rounding in poses composed in float stays far below this; a scaled or sheared matrix is far above.
constexpr double kRotationTolerance = 1e-4;

std::string edge_name(size_t i, const PoseGraphEdge& edge) {
  return "edge " + std::to_string(i) + " (" +
         (edge.kind == PoseGraphEdge::Kind::kLoop ? "loop" : "odometry") + ", node " +
         std::to_string(edge.from) + " to " + std::to_string(edge.to) + ")";
}

// Why `T` is not a rigid transform, or an empty string.
std::string pose_problem(const Pose& T) {
  if (!T.matrix().allFinite()) return "is not finite";
  if (!T.matrix().row(3).isApprox(Eigen::RowVector4d(0, 0, 0, 1)))
    return "has a last row that is not (0 0 0 1)";
  const Eigen::Matrix3d R = T.linear();
  const double orthonormality = orthonormality_error(T);
  if (orthonormality > kRotationTolerance || R.determinant() < 0) {
    std::ostringstream why;
    why << "has a linear part that is not a rotation (|R^T R - I| = " << orthonormality
        << ", det " << R.determinant() << ")";
    return why.str();
  }
  return {};
}

// S with S^T S = information, from its eigen-decomposition: a direction of zero (or rounding-
// negative) information gets a zero row and carries no weight, where Cholesky would fail.
Result<Matrix6d> whitening(const Matrix6d& information, const std::string& name) {
  if (!information.allFinite()) return invalid_argument(name + ": information is not finite");
  const double scale = information.cwiseAbs().maxCoeff();
  const double asymmetry = (information - information.transpose()).cwiseAbs().maxCoeff();
  if (asymmetry > kSymmetryTolerance * scale) {
    std::ostringstream why;
    why << name << ": information is not symmetric (max |I - I^T| = " << asymmetry
        << ", max |I| = " << scale << ")";
    return invalid_argument(why.str());
  }
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eigen(0.5 * (information + information.transpose()));
  if (eigen.info() != Eigen::Success)
    return invalid_argument(name + ": information has no eigen-decomposition");
  const Vector6d& eigenvalues = eigen.eigenvalues();  // ascending
  if (eigenvalues(0) < -kNegativeEigenvalueTolerance * scale) {
    std::ostringstream why;
    why << name << ": information is not positive semi-definite (eigenvalue " << eigenvalues(0)
        << ", largest " << eigenvalues(5) << ")";
    return invalid_argument(why.str());
  }
  return Matrix6d(eigenvalues.cwiseMax(0.0).cwiseSqrt().asDiagonal() *
                  eigen.eigenvectors().transpose());
}

Status check_options(const PoseGraphOptions& options, size_t nodes) {
  if (!(options.loop_loss_scale > 0) || !std::isfinite(options.loop_loss_scale))
    return invalid_argument("loop_loss_scale " + std::to_string(options.loop_loss_scale) +
                            " is not a positive number");
  if (!(options.loop_chi2_reject > 0))
    return invalid_argument("loop_chi2_reject " + std::to_string(options.loop_chi2_reject) +
                            " is not positive");
  if (options.max_iterations < 1)
    return invalid_argument("max_iterations " + std::to_string(options.max_iterations) +
                            " is less than 1");
  if (options.fixed_nodes.empty())
    return invalid_argument("no fixed node: at least one node must hold the graph in place");
  for (const uint32_t node : options.fixed_nodes) {
    if (node >= nodes)
      return invalid_argument("fixed node " + std::to_string(node) + " is out of range (" +
                              std::to_string(nodes) + " nodes)");
  }
  if (options.first_free_node >= nodes && nodes > 0)
    return invalid_argument("first free node " + std::to_string(options.first_free_node) +
                            " is out of range (" + std::to_string(nodes) + " nodes)");
  return Status::ok();
}

// The state Ceres optimises: per node a unit quaternion (x, y, z, w) and a translation, in arrays.
class NodeStates {
 public:
  explicit NodeStates(const std::vector<Pose>& T_world_node)
      : q_world_node_(4 * T_world_node.size()), t_world_node_(3 * T_world_node.size()) {
    for (size_t i = 0; i < T_world_node.size(); ++i) {
      Eigen::Map<Eigen::Quaterniond>(q(i)) = Eigen::Quaterniond(T_world_node[i].linear()).normalized();
      Eigen::Map<Eigen::Vector3d>(t(i)) = T_world_node[i].translation();
    }
  }
  double* q(size_t i) { return &q_world_node_[4 * i]; }
  double* t(size_t i) { return &t_world_node_[3 * i]; }
  const double* q(size_t i) const { return &q_world_node_[4 * i]; }
  const double* t(size_t i) const { return &t_world_node_[3 * i]; }

  size_t size() const { return t_world_node_.size() / 3; }
  Pose pose(size_t i) const {
    Pose T = Pose::Identity();
    // The solver keeps the quaternion on the unit sphere only to its tolerance.
    T.linear() = Eigen::Map<const Eigen::Quaterniond>(q(i)).normalized().toRotationMatrix();
    T.translation() = Eigen::Map<const Eigen::Vector3d>(t(i));
    return T;
  }

 private:
  std::vector<double> q_world_node_;  // 4 per node
  std::vector<double> t_world_node_;  // 3 per node
};

double chi2(const pose_graph::EdgeError& error, const PoseGraphEdge& edge, const NodeStates& states) {
  Vector6d residual;
  error(states.q(edge.from), states.t(edge.from), states.q(edge.to), states.t(edge.to),
        residual.data());
  return residual.squaredNorm();
}

ceres::Solver::Options solver_options(const PoseGraphOptions& options) {
  ceres::Solver::Options solver;
  solver.max_num_iterations = options.max_iterations;
  // The normal equations of a pose graph are sparse (a node meets its neighbours and a few loops):
  // sparse Cholesky with a fill-reducing ordering. SuiteSparse's CHOLMOD when Ceres has it (Debian's
  // does), else Eigen's.
  solver.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  solver.sparse_linear_algebra_library_type =
      ceres::IsSparseLinearAlgebraLibraryTypeAvailable(ceres::SUITE_SPARSE) ? ceres::SUITE_SPARSE
                                                                           : ceres::EIGEN_SPARSE;
  solver.num_threads = 1;  // it runs beside fusion on a 2-core machine
  // Levenberg's damping, the same in every direction, not Marquardt's diagonal of J^T J: a
  // direction that no edge sees (zero information) then gets no step and stays where the odometry
  // put it. The diagonal, unequal across the state, leaks the other directions' steps into it
  // (the test BlindDirectionsOfTheInformationStayFree), and took more iterations here.
  solver.jacobi_scaling = false;
  solver.min_lm_diagonal = 1.0;
  solver.max_lm_diagonal = 1.0;
  solver.logging_type = ceres::SILENT;
  solver.minimizer_progress_to_stdout = false;
  return solver;
}

// The checked input: every edge's error with its whitening.
Result<std::vector<pose_graph::EdgeError>> checked_edges(const std::vector<Pose>& T_world_node,
                                                         const std::vector<PoseGraphEdge>& edges,
                                                         const PoseGraphOptions& options) {
  const size_t nodes = T_world_node.size();
  DF_RETURN_IF_ERROR(check_options(options, nodes));
  for (size_t i = 0; i < nodes; ++i) {
    const std::string why = pose_problem(T_world_node[i]);
    if (!why.empty()) return invalid_argument("node " + std::to_string(i) + ": initial pose " + why);
  }
  std::vector<pose_graph::EdgeError> errors;
  errors.reserve(edges.size());
  for (size_t i = 0; i < edges.size(); ++i) {
    const PoseGraphEdge& edge = edges[i];
    const std::string name = edge_name(i, edge);
    if (edge.from >= nodes || edge.to >= nodes)
      return invalid_argument(name + ": node " + std::to_string(std::max(edge.from, edge.to)) +
                              " does not exist (" + std::to_string(nodes) + " nodes)");
    if (edge.from == edge.to) return invalid_argument(name + ": joins a node to itself");
    const std::string why = pose_problem(edge.T_from_to);
    if (!why.empty()) return invalid_argument(name + ": measured pose " + why);
    Result<Matrix6d> sqrt_information = whitening(edge.information, name);
    if (!sqrt_information) return sqrt_information.status();
    errors.push_back({Eigen::Quaterniond(edge.T_from_to.linear()).normalized().conjugate(),
                      edge.T_from_to.translation(), *sqrt_information});
  }
  return errors;
}

// Whether the solve moves an end of the edge (PoseGraphOptions::first_free_node): the others are
// left out of it, and a loop among fixed nodes is not judged again.
bool touches_free_node(const PoseGraphEdge& edge, const PoseGraphOptions& options) {
  return std::max(edge.from, edge.to) >= options.first_free_node;
}

// Ceres's cost of the edges in use: half the sum of their chi2, through the Cauchy loss of
// `loop_scale` for loops.
double cost(const std::vector<PoseGraphEdge>& edges, const std::vector<bool>& edge_used,
            const std::vector<double>& edge_chi2, double loop_scale) {
  ceres::CauchyLoss loop_loss(loop_scale);
  double sum = 0;
  for (size_t i = 0; i < edges.size(); ++i) {
    if (!edge_used[i]) continue;
    double rho[3] = {edge_chi2[i], 1, 0};
    if (edges[i].kind == PoseGraphEdge::Kind::kLoop) loop_loss.Evaluate(edge_chi2[i], rho);
    sum += rho[0];
  }
  return 0.5 * sum;
}

// Optimises `states` over the edges in use; returns the solver's iterations. While a loop's
// error is beyond the loss's scale, first by least squares: a redescending loss from the start
// would take a right closure after drift for an outlier, and pull too weakly to close it. Then,
// from there, with the loss: a wrong closure loses its pull and the map springs back.
Result<int> solve(const std::vector<PoseGraphEdge>& edges,
                  const std::vector<pose_graph::EdgeError>& errors, const std::vector<bool>& edge_used,
                  const PoseGraphOptions& options, NodeStates* states) {
  bool least_squares_first = false;
  for (size_t i = 0; i < edges.size(); ++i) {
    if (edge_used[i] && edges[i].kind == PoseGraphEdge::Kind::kLoop &&
        touches_free_node(edges[i], options))
      least_squares_first |= chi2(errors[i], edges[i], *states) >
                             options.loop_loss_scale * options.loop_loss_scale;
  }
  ceres::EigenQuaternionManifold quaternion_manifold;
  // No loss (least squares) until reset to Cauchy's.
  ceres::LossFunctionWrapper loop_loss(nullptr, ceres::TAKE_OWNERSHIP);
  ceres::Problem::Options problem_options;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  for (size_t i = 0; i < edges.size(); ++i) {
    if (!edge_used[i] || !touches_free_node(edges[i], options)) continue;
    const PoseGraphEdge& edge = edges[i];
    auto* cost = new ceres::AutoDiffCostFunction<pose_graph::EdgeError, 6, 4, 3, 4, 3>(
        new pose_graph::EdgeError(errors[i]));
    problem.AddResidualBlock(cost, edge.kind == PoseGraphEdge::Kind::kLoop ? &loop_loss : nullptr,
                             states->q(edge.from), states->t(edge.from), states->q(edge.to),
                             states->t(edge.to));
  }
  for (size_t node = 0; node < states->size(); ++node) {
    if (problem.HasParameterBlock(states->q(node)))
      problem.SetManifold(states->q(node), &quaternion_manifold);
  }
  auto fix = [&](size_t node) {
    if (!problem.HasParameterBlock(states->q(node))) return;  // in no edge: it stays anyway
    problem.SetParameterBlockConstant(states->q(node));
    problem.SetParameterBlockConstant(states->t(node));
  };
  for (const uint32_t node : options.fixed_nodes) fix(node);
  for (size_t node = 0; node < std::min<size_t>(options.first_free_node, states->size()); ++node)
    fix(node);
  const ceres::Solver::Options solver = solver_options(options);
  int iterations = 0;
  for (const bool robust : {false, true}) {
    if (!robust && !least_squares_first) continue;
    if (robust) loop_loss.Reset(new ceres::CauchyLoss(options.loop_loss_scale), ceres::TAKE_OWNERSHIP);
    ceres::Solver::Summary summary;
    ceres::Solve(solver, &problem, &summary);
    if (summary.termination_type == ceres::FAILURE || summary.termination_type == ceres::USER_FAILURE)
      return internal_error(summary.message);
    const int steps = summary.num_successful_steps + summary.num_unsuccessful_steps;
    iterations += steps;
    DF_LOG(PoseGraph, Debug) << (robust ? "robust" : "least squares") << ": cost "
                             << summary.initial_cost << " -> " << summary.final_cost << " in "
                             << steps << " iterations (" << summary.message << ")";
  }
  return iterations;
}

}  // namespace

Result<PoseGraphResult> optimise_pose_graph(const std::vector<Pose>& T_world_node_initial,
                                            const std::vector<PoseGraphEdge>& edges,
                                            const PoseGraphOptions& options) {
  Result<std::vector<pose_graph::EdgeError>> errors =
      checked_edges(T_world_node_initial, edges, options);
  if (!errors) return errors.status();
  route_solver_log();
  NodeStates states(T_world_node_initial);
  PoseGraphResult result;
  result.edge_used.assign(edges.size(), true);
  result.edge_chi2.assign(edges.size(), 0.0);
  for (size_t i = 0; i < edges.size(); ++i) result.edge_chi2[i] = chi2((*errors)[i], edges[i], states);
  result.initial_cost = cost(edges, result.edge_used, result.edge_chi2, options.loop_loss_scale);
  for (int round = 1; round <= kMaxRounds; ++round) {
    Result<int> iterations = solve(edges, *errors, result.edge_used, options, &states);
    if (!iterations)
      return iterations.status().with_context("pose graph optimisation, round " + std::to_string(round));
    result.iterations += *iterations;

    // A loop that the solution disagrees with is wrong, or the graph has no room for it: reject it
    // and solve again without it. A rejected loop is not taken back: against a solution without it
    // a right closure after drift looks as wrong as a wrong one.
    bool rejected = false;
    for (size_t i = 0; i < edges.size(); ++i) {
      result.edge_chi2[i] = chi2((*errors)[i], edges[i], states);
      const bool disagrees = !(result.edge_chi2[i] <= options.loop_chi2_reject);
      if (round < kMaxRounds && result.edge_used[i] && disagrees &&
          edges[i].kind == PoseGraphEdge::Kind::kLoop && touches_free_node(edges[i], options)) {
        result.edge_used[i] = false;
        ++result.loops_rejected;
        rejected = true;
      }
    }
    DF_LOG(PoseGraph, Debug) << "round " << round << ": " << *iterations << " iterations, "
                             << result.loops_rejected << " loops rejected so far";
    if (!rejected) break;
    // The next round starts again from the initial poses, not from this solution: a direction
    // that no edge left in use sees gets no step (solver_options()) and would stay where the
    // rejected loops pulled it, so that a wrong loop, rejected, would still bend the map.
    states = NodeStates(T_world_node_initial);
  }
  result.final_cost = cost(edges, result.edge_used, result.edge_chi2, options.loop_loss_scale);
  result.T_world_node.reserve(states.size());
  for (size_t i = 0; i < states.size(); ++i) result.T_world_node.push_back(states.pose(i));
  return result;
}

}  // namespace depthfuse
