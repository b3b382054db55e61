#pragma once
/// \file
/// SE(3) and SO(3) exponential, logarithm and adjoint (Barfoot, "State Estimation for Robotics",
/// ch. 7). Tangent vectors are ordered xi = [rho; phi] (translation part first), perturbations are
/// on the right: T = T_hat * exp(xi^). No Debian package ships Sophus, so these few functions are
/// written here and tested against their identities in tests/lie_test.cc.

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace concord::lie {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

/// [v]_x: the cross-product matrix, skew(a) * b == a.cross(b).
Eigen::Matrix3d skew(const Eigen::Vector3d& v);

/// Rodrigues' formula: exp(phi^) in SO(3).
Eigen::Matrix3d so3_exp(const Eigen::Vector3d& phi);

/// Inverse of so3_exp for rotation angles in [0, pi].
Eigen::Vector3d so3_log(const Eigen::Matrix3d& rotation);

/// Left Jacobian of SO(3), J_l(phi), so that t = J_l(phi) * rho in se3_exp.
Eigen::Matrix3d so3_left_jacobian(const Eigen::Vector3d& phi);

/// exp(xi^) in SE(3), xi = [rho; phi].
Eigen::Isometry3d se3_exp(const Vector6d& xi);

/// Inverse of se3_exp.
Vector6d se3_log(const Eigen::Isometry3d& pose);

/// Ad(T) = [R, [t]_x R; 0, R], so that T exp(xi^) T^-1 = exp((Ad(T) xi)^).
Matrix6d adjoint(const Eigen::Isometry3d& pose);

/// Covariance of the right perturbation xi_r (T = T_hat exp(xi_r^)) from that of the left one
/// xi_l (T = exp(xi_l^) T_hat): xi_r = Ad(T_hat^-1) xi_l.
Matrix6d right_from_left_covariance(const Eigen::Isometry3d& T_hat, const Matrix6d& left);

/// The inverse map: xi_l = Ad(T_hat) xi_r.
Matrix6d left_from_right_covariance(const Eigen::Isometry3d& T_hat, const Matrix6d& right);

/// Makes the rotation block exactly orthonormal (guards against round-off growth after many
/// products). Returns the nearest rotation in the Frobenius sense.
Eigen::Isometry3d orthonormalized(const Eigen::Isometry3d& pose);

}  // namespace concord::lie
