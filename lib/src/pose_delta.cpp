#include "depthfuse/pose_delta.hpp"

namespace depthfuse {

Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d S;
  S << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return S;
}

Vector6d pose_delta(const Pose& T_ref, const Pose& T) {
  const Eigen::Matrix3d R = T_ref.linear().transpose() * T.linear();
  const Eigen::AngleAxisd aa(R);
  Vector6d d;
  d.head<3>() = aa.angle() * aa.axis();
  d.tail<3>() = T_ref.linear().transpose() * (T.translation() - T_ref.translation());
  return d;
}

Pose apply_delta(const Pose& T_ref, const Vector6d& delta) {
  Pose T = T_ref;
  const double angle = delta.head<3>().norm();
  if (angle > 1e-15)
    T.linear() = T_ref.linear() * Eigen::AngleAxisd(angle, delta.head<3>() / angle).toRotationMatrix();
  T.translation() = T_ref.translation() + T_ref.linear() * delta.tail<3>();
  return T;
}

Matrix6d delta_adjoint(const Pose& X_a_b) {
  const Eigen::Matrix3d Rt = X_a_b.linear().transpose();
  Matrix6d J = Matrix6d::Zero();
  J.topLeftCorner<3, 3>() = Rt;
  J.bottomRightCorner<3, 3>() = Rt;
  J.bottomLeftCorner<3, 3>() = -Rt * skew(X_a_b.translation());
  return J;
}

double orthonormality_error(const Pose& T) {
  const Eigen::Matrix3d R = T.linear();
  return (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
}

Pose orthonormalised(const Pose& T) {
  Pose out = T;
  out.linear() = Eigen::Quaterniond(T.linear()).normalized().toRotationMatrix();
  return out;
}

}  // namespace depthfuse
