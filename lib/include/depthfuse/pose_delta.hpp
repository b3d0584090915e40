// A pose's small change as a right perturbation, the one convention of the motion prior, the
// registration's information and the pose graph's edges: T = T_ref * [exp(w) | v], the 6-vector
// delta = [w (rad); v (m)], rotation first, both in T_ref's frame.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "depthfuse/types.hpp"

namespace depthfuse {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

// The delta that turns T_ref into T.
Vector6d pose_delta(const Pose& T_ref, const Pose& T);
// T_ref moved by delta.
Pose apply_delta(const Pose& T_ref, const Vector6d& delta);
// The cross-product matrix: skew(v) * w = v x w.
Eigen::Matrix3d skew(const Eigen::Vector3d& v);
// For a pose B = A * X_a_b: a small delta of A, with X_a_b held, is the delta
// delta_adjoint(X_a_b) * delta_A of B. Covariances move with it: C_B = J C_A J^T.
Matrix6d delta_adjoint(const Pose& X_a_b);
// T with its rotation made orthonormal again: poses composed over and over (a keyframe moved by
// correction after correction) drift off the rotations by rounding, and the map's deformation
// refuses a pose that is not rigid.
Pose orthonormalised(const Pose& T);
// How far T's linear part is from orthonormal: the largest |R^T R - I| entry (0 for a rotation).
double orthonormality_error(const Pose& T);

}  // namespace depthfuse
