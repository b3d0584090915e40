// The pose graph optimiser: loop closure puts its correction where the odometry was blind, a wrong
// closure is rejected without bending the map, blind directions stay free, bad input is named.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>

#include <ceres/jet.h>

#include "depthfuse/pose_graph.hpp"
#include "pose_graph_error.hpp"  // internal: the edge's error, checked against its definition

namespace depthfuse {
namespace {

using Kind = PoseGraphEdge::Kind;

// SE(3)'s exponential, rotation first: the inverse of the error's Log.
Pose exp_se3(const Vector6d& xi) {
  const Eigen::Vector3d w = xi.head<3>();
  const double theta = w.norm();
  Eigen::Matrix3d W;
  W << 0, -w.z(), w.y(), w.z(), 0, -w.x(), -w.y(), w.x(), 0;
  Eigen::Matrix3d V = Eigen::Matrix3d::Identity();
  if (theta > 1e-9) {
    V += (1 - std::cos(theta)) / (theta * theta) * W +
         (theta - std::sin(theta)) / (theta * theta * theta) * W * W;
  }
  Pose T = Pose::Identity();
  if (theta > 0) T.linear() = Eigen::AngleAxisd(theta, w / theta).toRotationMatrix();
  T.translation() = V * xi.tail<3>();
  return T;
}

Vector6d vec6(double rx, double ry, double rz, double tx, double ty, double tz) {
  Vector6d v;
  v << rx, ry, rz, tx, ty, tz;
  return v;
}

Pose translation(double x, double y, double z) {
  Pose T = Pose::Identity();
  T.translation() = Eigen::Vector3d(x, y, z);
  return T;
}

Matrix6d diagonal(double rotation, double tx, double ty, double tz) {
  return vec6(rotation, rotation, rotation, tx, ty, tz).asDiagonal();
}

// How far apart two poses are: translation in m, rotation in rad.
double metres_apart(const Pose& a, const Pose& b) {
  return (a.translation() - b.translation()).norm();
}
double radians_apart(const Pose& a, const Pose& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
}

// A walk around a 2 x 2 m square, 4 steps of 0.5 m a side and a quarter turn at each corner, each
// pose shaken by a few cm and degrees so that nothing is planar: 16 nodes, the step after the last
// one leads back to the first.
std::vector<Pose> square_walk() {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> shake(-1.0, 1.0);
  std::vector<Pose> T_world_node;
  Pose walk = Pose::Identity();
  for (int k = 0; k < 16; ++k) {
    T_world_node.push_back(walk * exp_se3(vec6(0.03 * shake(rng), 0.03 * shake(rng), 0.03 * shake(rng),
                                               0.02 * shake(rng), 0.02 * shake(rng), 0.02 * shake(rng))));
    walk = walk * translation(0.5, 0, 0);
    if (k % 4 == 3) walk.rotate(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()));
  }
  return T_world_node;
}

const Matrix6d kOdometryInformation = diagonal(1e4, 1e4, 1e4, 1e4);  // 1 cm, 0.6 degrees
constexpr uint32_t kBlindEdge = 5;  // node 5 to 6, along the square's second side

struct Graph {
  std::vector<Pose> T_world_truth;
  std::vector<Pose> T_world_initial;  // the odometry's
  std::vector<PoseGraphEdge> edges;
};

// Odometry along the square; edge kBlindEdge fell 20 cm short along its `to` frame's x and knew
// nothing of x (information `blind_x` there), the other edges measured the truth. The initial poses
// are the odometry's, 20 cm off at the end. No loop yet.
Graph drifted_square(double blind_x) {
  Graph g;
  g.T_world_truth = square_walk();
  g.T_world_initial.push_back(g.T_world_truth[0]);
  for (uint32_t k = 0; k + 1 < g.T_world_truth.size(); ++k) {
    PoseGraphEdge edge;
    edge.from = k;
    edge.to = k + 1;
    edge.T_from_to = g.T_world_truth[k].inverse() * g.T_world_truth[k + 1];
    edge.information = kOdometryInformation;
    if (k == kBlindEdge) {
      edge.T_from_to = edge.T_from_to * translation(-0.2, 0, 0);
      edge.information = diagonal(1e4, blind_x, 1e4, 1e4);
    }
    g.T_world_initial.push_back(g.T_world_initial.back() * edge.T_from_to);
    g.edges.push_back(edge);
  }
  return g;
}

PoseGraphEdge loop_edge(const std::vector<Pose>& T_world_truth, uint32_t from, uint32_t to,
                        const Pose& measurement_error = Pose::Identity()) {
  PoseGraphEdge edge;
  edge.kind = Kind::kLoop;
  edge.from = from;
  edge.to = to;
  edge.T_from_to = T_world_truth[from].inverse() * T_world_truth[to] * measurement_error;
  edge.information = diagonal(1e4, 1e4, 1e4, 1e4);
  return edge;
}

// The closing loop from the last node back to the first.
void close_square(Graph* g) { g->edges.push_back(loop_edge(g->T_world_truth, 15, 0)); }

void expect_poses_near(const std::vector<Pose>& actual, const std::vector<Pose>& expected,
                       double metres, double radians) {
  ASSERT_EQ(actual.size(), expected.size());
  for (size_t i = 0; i < actual.size(); ++i) {
    EXPECT_LT(metres_apart(actual[i], expected[i]), metres) << "node " << i;
    EXPECT_LT(radians_apart(actual[i], expected[i]), radians) << "node " << i;
  }
}

void check_closed_square(double blind_x) {
  Graph g = drifted_square(blind_x);
  close_square(&g);
  ASSERT_GT(metres_apart(g.T_world_initial[15], g.T_world_truth[15]), 0.19);  // the drift is there

  const Result<PoseGraphResult> r = optimise_pose_graph(g.T_world_initial, g.edges);
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  expect_poses_near(r->T_world_node, g.T_world_truth, 1e-4, 1e-5);
  EXPECT_TRUE(r->T_world_node[0].isApprox(g.T_world_initial[0], 1e-12));  // the gauge held
  EXPECT_EQ(r->loops_rejected, 0u);
  EXPECT_TRUE(r->edge_used.back());
  EXPECT_LT(r->final_cost, 1e-6 * r->initial_cost);
  // The blind edge took the 20 cm along its x; every other edge kept its measured relative pose.
  for (uint32_t k = 0; k + 1 < 16; ++k) {
    const Pose T_from_to = r->T_world_node[k].inverse() * r->T_world_node[k + 1];
    const Pose T_measured_to = g.edges[k].T_from_to.inverse() * T_from_to;
    if (k == kBlindEdge) {
      EXPECT_NEAR(T_measured_to.translation().x(), 0.2, 1e-4);
    } else {
      EXPECT_LT(T_measured_to.translation().norm(), 1e-4) << "edge " << k;
      EXPECT_LT(r->edge_chi2[k], 1e-3) << "edge " << k;
    }
  }
}

TEST(PoseGraph, LoopClosureCorrectsWhereTheOdometryWasBlind) { check_closed_square(1e-6); }

// Zero information along x: accepted (no Cholesky to fail), and the axis is free.
TEST(PoseGraph, ZeroInformationAlongAnAxisIsAcceptedAndFree) { check_closed_square(0.0); }

TEST(PoseGraph, WrongLoopBesideARightOneIsRejectedAndTheMapNotBent) {
  Graph g = drifted_square(1e-6);
  close_square(&g);
  // Across the square, 1 m off: as confident as the right one.
  g.edges.push_back(loop_edge(g.T_world_truth, 3, 11, translation(1.0, 0, 0)));
  testing::internal::CaptureStdout();
  testing::internal::CaptureStderr();
  const Result<PoseGraphResult> r = optimise_pose_graph(g.T_world_initial, g.edges);
  EXPECT_EQ(testing::internal::GetCapturedStderr(), "");  // the solver is silent
  EXPECT_EQ(testing::internal::GetCapturedStdout(), "");
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  EXPECT_FALSE(r->edge_used.back());
  EXPECT_TRUE(r->edge_used[g.edges.size() - 2]);
  EXPECT_EQ(r->loops_rejected, 1u);
  EXPECT_GT(r->edge_chi2.back(), 1000.0);  // it is reported, at the solution without it
  expect_poses_near(r->T_world_node, g.T_world_truth, 1e-3, 1e-4);
}

TEST(PoseGraph, WrongLoopAloneIsRejectedAndThePosesStayTheOdometrys) {
  Graph g = drifted_square(1e4);  // every direction seen: the odometry is the map
  g.edges.push_back(loop_edge(g.T_world_truth, 3, 11, translation(1.0, 0, 0)));
  const Result<PoseGraphResult> r = optimise_pose_graph(g.T_world_initial, g.edges);
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  EXPECT_FALSE(r->edge_used.back());
  EXPECT_EQ(r->loops_rejected, 1u);
  expect_poses_near(r->T_world_node, g.T_world_initial, 1e-4, 1e-5);
}

// Where the odometry was blind, a wrong loop pulls the nodes beyond it along the blind direction
// before it is rejected; nothing pulls them back (a direction no edge sees gets no step), so the
// solution without it must start again from the initial poses, or the rejected loop bends the map.
TEST(PoseGraph, ARejectedLoopLeavesNoTraceWhereTheOdometryWasBlind) {
  for (const double blind_x : {0.0, 1e-6}) {
    SCOPED_TRACE("information along the blind edge's x: " + std::to_string(blind_x));
    Graph g = drifted_square(blind_x);
    // Across the square, off by 1 m along the blind direction and 0.5 m across it.
    g.edges.push_back(loop_edge(g.T_world_truth, 3, 11, translation(1.0, 0.5, 0)));
    const Result<PoseGraphResult> r = optimise_pose_graph(g.T_world_initial, g.edges);
    ASSERT_TRUE(r.is_ok()) << r.status().to_string();
    EXPECT_FALSE(r->edge_used.back());
    EXPECT_EQ(r->loops_rejected, 1u);
    expect_poses_near(r->T_world_node, g.T_world_initial, 1e-4, 1e-5);
  }
}

// One edge, node 0 fixed, node 1 started `offset` (in the measurement's frame) away from where the
// edge puts it; the information is blind along the unit direction `blind` of the translation.
void check_blind_direction(const Eigen::Vector3d& blind) {
  const Pose T_world_0 = exp_se3(vec6(0.1, -0.2, 0.3, 1, 2, 3));
  PoseGraphEdge edge;
  edge.T_from_to = exp_se3(vec6(-0.05, 0.02, 0.4, 0.5, 0.1, -0.2));
  edge.from = 0;
  edge.to = 1;
  edge.information = diagonal(1e4, 1e4, 1e4, 1e4);
  edge.information.bottomRightCorner<3, 3>() = 1e4 * (Eigen::Matrix3d::Identity() - blind * blind.transpose());
  const Eigen::Vector3d offset = 0.3 * blind + Eigen::Vector3d(0.02, -0.05, 0.04);
  const Pose T_world_1 = T_world_0 * edge.T_from_to * translation(offset.x(), offset.y(), offset.z());

  const Result<PoseGraphResult> r = optimise_pose_graph({T_world_0, T_world_1}, {edge});
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  const Pose T_measured_1 = edge.T_from_to.inverse() * T_world_0.inverse() * r->T_world_node[1];
  // Along the blind direction node 1 stays where it started; the rest is pulled to the edge.
  EXPECT_NEAR(T_measured_1.translation().dot(blind), offset.dot(blind), 1e-6);
  EXPECT_LT((T_measured_1.translation() - offset.dot(blind) * blind).norm(), 1e-6);
  EXPECT_LT(radians_apart(T_measured_1, Pose::Identity()), 1e-6);
  EXPECT_LT(r->edge_chi2[0], 1e-6);
}

TEST(PoseGraph, BlindDirectionsOfTheInformationStayFree) {
  check_blind_direction(Eigen::Vector3d::UnitX());
  check_blind_direction(Eigen::Vector3d(1, 1, 0).normalized());
}

// The optimised error is the definition's: for T_world_to = T_world_from * T_from_to * Exp(xi) it
// is xi, at generic angles, near zero (where the closed forms divide 0 by 0) and near pi.
TEST(PoseGraph, EdgeErrorIsTheLogOfARightPerturbation) {
  const Pose T_world_from = exp_se3(vec6(0.3, 0.1, -0.7, 1, -2, 0.5));
  const Pose T_from_to = exp_se3(vec6(-0.2, 0.5, 0.1, 0.3, 0.2, -0.1));
  pose_graph::EdgeError error{Eigen::Quaterniond(T_from_to.linear()).conjugate(),
                              T_from_to.translation(), Matrix6d::Identity()};
  for (const Vector6d& xi :
       {vec6(0.5, -0.3, 0.2, 1.0, 2.0, -0.5), vec6(1e-7, -2e-7, 3e-7, 0.1, -0.2, 0.3),
        vec6(0.004, 0.003, -0.005, 0.1, -0.2, 0.3), vec6(0, 0, 0, 0.4, 0.5, 0.6),
        vec6(0, 0, 3.1, 0.4, 0.5, 0.6), vec6(0, 0, 0, 0, 0, 0)}) {
    const Pose T_world_to = T_world_from * T_from_to * exp_se3(xi);
    const Eigen::Quaterniond q_from(T_world_from.linear()), q_to(T_world_to.linear());
    const Eigen::Vector3d t_from = T_world_from.translation(), t_to = T_world_to.translation();
    Vector6d e;
    ASSERT_TRUE(error(q_from.coeffs().data(), t_from.data(), q_to.coeffs().data(), t_to.data(), e.data()));
    EXPECT_LT((e - xi).norm(), 1e-9) << "xi " << xi.transpose() << " e " << e.transpose();
  }
}

// Its automatic derivatives match central differences in every branch of the Log, including at a
// zero error, where a solution is.
TEST(PoseGraph, EdgeErrorDerivativesMatchFiniteDifferences) {
  using Jet = ceres::Jet<double, 14>;
  const Pose T_world_from = exp_se3(vec6(0.3, 0.1, -0.7, 1, -2, 0.5));
  const Pose T_from_to = exp_se3(vec6(-0.2, 0.5, 0.1, 0.3, 0.2, -0.1));
  Matrix6d sqrt_information = Matrix6d::Identity();
  sqrt_information(3, 4) = 0.5;
  pose_graph::EdgeError error{Eigen::Quaterniond(T_from_to.linear()).conjugate(),
                              T_from_to.translation(), sqrt_information};
  for (const Vector6d& xi : {vec6(0.5, -0.3, 0.2, 1.0, 2.0, -0.5), vec6(0, 0, 0, 0, 0, 0),
                             vec6(0.004, 0.003, -0.005, 0.1, -0.2, 0.3),
                             vec6(0.006, 0.006, 0.006, 0.1, -0.2, 0.3)}) {
    const Pose T_world_to = T_world_from * T_from_to * exp_se3(xi);
    Eigen::Matrix<double, 14, 1> x;
    x << Eigen::Quaterniond(T_world_from.linear()).coeffs(), T_world_from.translation(),
        Eigen::Quaterniond(T_world_to.linear()).coeffs(), T_world_to.translation();
    Eigen::Matrix<Jet, 14, 1> x_jet;
    for (int i = 0; i < 14; ++i) x_jet(i) = Jet(x(i), i);
    Eigen::Matrix<Jet, 6, 1> e_jet;
    error(&x_jet(0), &x_jet(4), &x_jet(7), &x_jet(11), e_jet.data());
    for (int i = 0; i < 14; ++i) {
      const double h = 1e-6;
      Eigen::Matrix<double, 14, 1> plus = x, minus = x;
      plus(i) += h;
      minus(i) -= h;
      Vector6d e_plus, e_minus;
      error(&plus(0), &plus(4), &plus(7), &plus(11), e_plus.data());
      error(&minus(0), &minus(4), &minus(7), &minus(11), e_minus.data());
      const Vector6d numeric = (e_plus - e_minus) / (2 * h);
      for (int row = 0; row < 6; ++row)
        EXPECT_NEAR(e_jet(row).v(i), numeric(row), 1e-6) << "xi " << xi.transpose() << " d" << row << "/d" << i;
    }
  }
}

// A window of the newest nodes solved (the loop closer's, in a long scan): the nodes before it stay
// where they were, a loop between two of them is neither solved nor judged (a wrong one, 1 m off,
// here), and the free nodes close the square against them, the blind edge taking the drift.
TEST(PoseGraph, NodesBeforeTheFirstFreeOneStayAndTheirLoopsAreLeftOut) {
  Graph g = drifted_square(1e-6);
  close_square(&g);
  g.edges.push_back(loop_edge(g.T_world_truth, 1, 3, translation(1.0, 0, 0)));
  PoseGraphOptions options;
  options.first_free_node = kBlindEdge + 1;
  const Result<PoseGraphResult> r = optimise_pose_graph(g.T_world_initial, g.edges, options);
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  for (uint32_t k = 0; k < options.first_free_node; ++k)
    EXPECT_TRUE(r->T_world_node[k].isApprox(g.T_world_initial[k], 1e-12)) << "node " << k;
  expect_poses_near(r->T_world_node, g.T_world_truth, 1e-4, 1e-5);
  EXPECT_EQ(r->loops_rejected, 0u);
  EXPECT_TRUE(r->edge_used.back()) << "a loop among fixed nodes was judged";

  // The whole graph free: the wrong loop is found out.
  const Result<PoseGraphResult> all = optimise_pose_graph(g.T_world_initial, g.edges);
  ASSERT_TRUE(all.is_ok()) << all.status().to_string();
  EXPECT_FALSE(all->edge_used.back());
}

// A valid little graph for the bad-input cases to spoil one thing each.
struct Small {
  std::vector<Pose> T_world_node{Pose::Identity(), translation(1, 0, 0), translation(2, 0, 0)};
  std::vector<PoseGraphEdge> edges{PoseGraphEdge{0, 1, translation(1, 0, 0)},
                                   PoseGraphEdge{1, 2, translation(1, 0, 0)}};
  PoseGraphOptions options;
};

void expect_invalid(const Small& s, const std::string& named, const std::string& why) {
  const Result<PoseGraphResult> r = optimise_pose_graph(s.T_world_node, s.edges, s.options);
  ASSERT_FALSE(r.is_ok()) << named << ": " << why;
  EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find(named), std::string::npos) << r.status().message();
  EXPECT_NE(r.status().message().find(why), std::string::npos) << r.status().message();
}

TEST(PoseGraph, BadInputIsAnErrorNamingTheEdgeOrNode) {
  ASSERT_TRUE(optimise_pose_graph(Small().T_world_node, Small().edges).is_ok());
  const double nan = std::nan("");
  {
    Small s;
    s.edges[1].to = 7;
    expect_invalid(s, "edge 1", "node 7 does not exist");
  }
  {
    Small s;
    s.edges[0].to = 0;
    expect_invalid(s, "edge 0", "to itself");
  }
  {
    Small s;
    s.T_world_node[2].translation().y() = nan;
    expect_invalid(s, "node 2", "not finite");
  }
  {
    Small s;
    s.T_world_node[1].linear()(0, 0) = 2;
    expect_invalid(s, "node 1", "not a rotation");
  }
  {
    Small s;
    s.edges[1].T_from_to.linear()(1, 2) = nan;
    expect_invalid(s, "edge 1", "measured pose is not finite");
  }
  {
    Small s;
    s.edges[0].information(4, 4) = INFINITY;
    expect_invalid(s, "edge 0", "information is not finite");
  }
  {
    Small s;
    s.edges[1].information(0, 5) = 0.5;
    expect_invalid(s, "edge 1", "not symmetric");
  }
  {
    Small s;
    s.edges[1].information(3, 3) = -1e-3;  // a small negative eigenvalue is not rounding
    expect_invalid(s, "edge 1", "not positive semi-definite");
  }
  {
    Small s;
    s.edges[0].information(0, 1) = s.edges[0].information(1, 0) = 2;  // symmetric, eigenvalue -1
    expect_invalid(s, "edge 0", "not positive semi-definite");
  }
  {
    Small s;
    s.options.fixed_nodes.clear();
    expect_invalid(s, "no fixed node", "");
  }
  {
    Small s;
    s.options.fixed_nodes = {0, 3};
    expect_invalid(s, "fixed node 3", "out of range");
  }
  {
    Small s;
    s.options.loop_loss_scale = 0;
    expect_invalid(s, "loop_loss_scale", "");
  }
  {
    Small s;
    s.options.loop_chi2_reject = nan;
    expect_invalid(s, "loop_chi2_reject", "");
  }
  {
    Small s;
    s.options.max_iterations = 0;
    expect_invalid(s, "max_iterations", "");
  }
  {
    Small s;
    s.options.first_free_node = 3;
    expect_invalid(s, "first free node 3", "out of range");
  }
}

TEST(PoseGraph, NodesInNoEdgeKeepTheirPose) {
  Small s;
  s.T_world_node.push_back(exp_se3(vec6(0.1, 0.2, 0.3, 4, 5, 6)));
  s.T_world_node[2] = translation(2.5, 0, 0);
  const Result<PoseGraphResult> r = optimise_pose_graph(s.T_world_node, s.edges);
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  EXPECT_LT(metres_apart(r->T_world_node[2], translation(2, 0, 0)), 1e-6);
  EXPECT_TRUE(r->T_world_node[3].isApprox(s.T_world_node[3], 1e-12));
}

TEST(PoseGraph, NothingToOptimiseIsNoError) {
  const Small s;
  const Result<PoseGraphResult> no_edges = optimise_pose_graph(s.T_world_node, {});
  ASSERT_TRUE(no_edges.is_ok()) << no_edges.status().to_string();
  EXPECT_EQ(no_edges->T_world_node.size(), 3u);
  PoseGraphOptions all_fixed;
  all_fixed.fixed_nodes = {0, 1, 2};
  const Result<PoseGraphResult> fixed = optimise_pose_graph(s.T_world_node, s.edges, all_fixed);
  ASSERT_TRUE(fixed.is_ok()) << fixed.status().to_string();
  EXPECT_TRUE(fixed->T_world_node[2].isApprox(s.T_world_node[2], 1e-12));
}

}  // namespace
}  // namespace depthfuse
