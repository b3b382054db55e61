#pragma once
/// \file
/// The rigid transform between two robots' frames from corresponding object positions, with its
/// covariance: a weighted closed form (Horn's method in Umeyama's SVD form, weights from the
/// covariances) as the start, Gauss-Newton on the Mahalanobis residuals
///   r_k = p_target_k - T p_source_k,  r_k ~ N(0, C_target_k + R C_source_k R^T),
/// and the covariance of T as a left perturbation in the target frame, T = exp(eps^) T_hat,
/// eps = [rho; phi] (the estimator's convention, state.h).
///
/// The objects of one map share their robot's drift, so their errors are correlated in a way a
/// compact map description does not carry. The covariance is therefore that of covariance
/// intersection over the correspondences (the information of the fit divided by their number),
/// consistent whatever those correlations, scaled up by the fit's own residuals when they exceed
/// what the covariances predict.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <optional>
#include <vector>

#include "concord/estimator/lie.h"

namespace concord::association {

/// One correspondence: the same object in the target and in the source frame.
struct PointPair {
  Eigen::Vector3d p_target = Eigen::Vector3d::Zero();
  Eigen::Vector3d p_source = Eigen::Vector3d::Zero();
  Eigen::Matrix3d covariance_target = Eigen::Matrix3d::Identity();
  Eigen::Matrix3d covariance_source = Eigen::Matrix3d::Identity();
};

/// The result of align_points.
struct RigidAlignment {
  /// Maps source coordinates into the target frame.
  Eigen::Isometry3d T_target_source = Eigen::Isometry3d::Identity();
  /// Covariance of eps, T = exp(eps^) T_hat (left perturbation, target frame), 6x6 on [rho; phi].
  lie::Matrix6d covariance = lie::Matrix6d::Identity();
  /// Sum of the squared Mahalanobis residuals at the solution.
  double chi2 = 0.0;
  /// Largest squared Mahalanobis residual of one correspondence.
  double largest_residual = 0.0;
};

/// Weighted closed-form alignment (Horn/Umeyama): the rotation and translation minimizing
/// sum w_k ||p_target_k - T p_source_k||^2, a proper rotation. Needs >= 3 pairs (asserted) and
/// positive weights; with collinear points the rotation about their line is arbitrary.
Eigen::Isometry3d weighted_horn(const std::vector<PointPair>& pairs,
                                const std::vector<double>& weights);

/// Alignment with covariance (see the file comment). nullopt with fewer than 3 pairs, a covariance
/// that is not positive definite, or a geometry that does not fix the transform (collinear
/// points: the information of the fit has a reciprocal condition number below 1e-9).
std::optional<RigidAlignment> align_points(const std::vector<PointPair>& pairs,
                                           int gauss_newton_iterations = 5);

/// The composition T_a_c = T_a_b T_b_c of two uncertain transforms with independent errors,
/// covariances as left perturbations in their target frames:
///   Sigma_a_c = Sigma_a_b + Ad(T_a_b) Sigma_b_c Ad(T_a_b)^T.
lie::Matrix6d compose_covariance(const Eigen::Isometry3d& T_a_b,
                                 const lie::Matrix6d& covariance_a_b,
                                 const lie::Matrix6d& covariance_b_c);

/// Covariance of T^-1 (left perturbation in its target frame) from that of T:
/// Ad(T^-1) Sigma Ad(T^-1)^T.
lie::Matrix6d inverse_covariance(const Eigen::Isometry3d& T, const lie::Matrix6d& covariance);

}  // namespace concord::association
