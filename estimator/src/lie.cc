#include "concord/estimator/lie.h"

#include <Eigen/SVD>
#include <cmath>

namespace concord::lie {

namespace {
constexpr double kSmallAngle = 1e-8;
}

Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return m;
}

Eigen::Matrix3d so3_exp(const Eigen::Vector3d& phi) {
  const double angle = phi.norm();
  const Eigen::Matrix3d phi_hat = skew(phi);
  if (angle < kSmallAngle) {
    return Eigen::Matrix3d::Identity() + phi_hat + 0.5 * phi_hat * phi_hat;
  }
  const double a = std::sin(angle) / angle;
  const double b = (1.0 - std::cos(angle)) / (angle * angle);
  return Eigen::Matrix3d::Identity() + a * phi_hat + b * phi_hat * phi_hat;
}

Eigen::Vector3d so3_log(const Eigen::Matrix3d& rotation) {
  // Eigen's AngleAxis handles the angle-near-pi case robustly.
  const Eigen::AngleAxisd angle_axis(rotation);
  const double angle = angle_axis.angle();
  if (angle < kSmallAngle) {
    // First order: R - R^T = 2 phi^.
    return 0.5 * Eigen::Vector3d(rotation(2, 1) - rotation(1, 2), rotation(0, 2) - rotation(2, 0),
                                 rotation(1, 0) - rotation(0, 1));
  }
  return angle * angle_axis.axis();
}

Eigen::Matrix3d so3_left_jacobian(const Eigen::Vector3d& phi) {
  const double angle = phi.norm();
  const Eigen::Matrix3d phi_hat = skew(phi);
  if (angle < kSmallAngle) {
    return Eigen::Matrix3d::Identity() + 0.5 * phi_hat + phi_hat * phi_hat / 6.0;
  }
  const double angle2 = angle * angle;
  const double a = (1.0 - std::cos(angle)) / angle2;
  const double b = (angle - std::sin(angle)) / (angle2 * angle);
  return Eigen::Matrix3d::Identity() + a * phi_hat + b * phi_hat * phi_hat;
}

Eigen::Isometry3d se3_exp(const Vector6d& xi) {
  const Eigen::Vector3d rho = xi.head<3>();
  const Eigen::Vector3d phi = xi.tail<3>();
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = so3_exp(phi);
  pose.translation() = so3_left_jacobian(phi) * rho;
  return pose;
}

Vector6d se3_log(const Eigen::Isometry3d& pose) {
  const Eigen::Vector3d phi = so3_log(pose.linear());
  Vector6d xi;
  xi.head<3>() = so3_left_jacobian(phi).inverse() * pose.translation();
  xi.tail<3>() = phi;
  return xi;
}

Matrix6d adjoint(const Eigen::Isometry3d& pose) {
  Matrix6d ad = Matrix6d::Zero();
  const Eigen::Matrix3d rotation = pose.linear();
  ad.topLeftCorner<3, 3>() = rotation;
  ad.topRightCorner<3, 3>() = skew(pose.translation()) * rotation;
  ad.bottomRightCorner<3, 3>() = rotation;
  return ad;
}

Eigen::Isometry3d orthonormalized(const Eigen::Isometry3d& pose) {
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(pose.linear(),
                                              Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d rotation = svd.matrixU() * svd.matrixV().transpose();
  if (rotation.determinant() < 0.0) {
    Eigen::Matrix3d u = svd.matrixU();
    u.col(2) *= -1.0;
    rotation = u * svd.matrixV().transpose();
  }
  Eigen::Isometry3d out = pose;
  out.linear() = rotation;
  return out;
}

Matrix6d right_from_left_covariance(const Eigen::Isometry3d& T_hat, const Matrix6d& left) {
  const Matrix6d A = adjoint(T_hat.inverse());
  const Matrix6d right = A * left * A.transpose();
  return 0.5 * (right + right.transpose());
}

Matrix6d left_from_right_covariance(const Eigen::Isometry3d& T_hat, const Matrix6d& right) {
  const Matrix6d A = adjoint(T_hat);
  const Matrix6d left = A * right * A.transpose();
  return 0.5 * (left + left.transpose());
}

}  // namespace concord::lie
