#include "concord/association/alignment.h"

#include <Eigen/Cholesky>
#include <Eigen/SVD>
#include <cassert>

#include "concord/estimator/symmetric3.h"

namespace concord::association {

Eigen::Isometry3d weighted_horn(const std::vector<PointPair>& pairs,
                                const std::vector<double>& weights) {
  assert(pairs.size() >= 3 && pairs.size() == weights.size());
  // 1. Weighted centroids.
  double total = 0.0;
  Eigen::Vector3d centroid_target = Eigen::Vector3d::Zero();
  Eigen::Vector3d centroid_source = Eigen::Vector3d::Zero();
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    total += weights[k];
    centroid_target += weights[k] * pairs[k].p_target;
    centroid_source += weights[k] * pairs[k].p_source;
  }
  centroid_target /= total;
  centroid_source /= total;
  // 2. Cross-covariance and its SVD (Umeyama): R = U diag(1, 1, det(U V^T)) V^T.
  Eigen::Matrix3d cross = Eigen::Matrix3d::Zero();
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    cross += weights[k] * (pairs[k].p_target - centroid_target) *
             (pairs[k].p_source - centroid_source).transpose();
  }
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(cross, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d sign = Eigen::Matrix3d::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0.0) sign(2, 2) = -1.0;
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = svd.matrixU() * sign * svd.matrixV().transpose();
  T.translation() = centroid_target - T.linear() * centroid_source;
  return T;
}

std::optional<RigidAlignment> align_points(const std::vector<PointPair>& pairs,
                                           int gauss_newton_iterations) {
  if (pairs.size() < 3) return std::nullopt;
  // 1. Closed-form start, each pair weighted by its mean precision.
  std::vector<double> weights;
  weights.reserve(pairs.size());
  for (const PointPair& pair : pairs) {
    const double trace = (pair.covariance_target + pair.covariance_source).trace();
    if (!(trace > 0.0)) return std::nullopt;
    weights.push_back(3.0 / trace);
  }
  Eigen::Isometry3d T = weighted_horn(pairs, weights);

  // 2. Gauss-Newton on the Mahalanobis residuals, left perturbation:
  //    r_k(eps) = p_t - exp(eps^) T p_s,  dr/deps = -[I, -[T p_s]_x].
  lie::Matrix6d information = lie::Matrix6d::Zero();
  double chi2 = 0.0;
  double largest = 0.0;
  for (int iteration = 0; iteration <= gauss_newton_iterations; ++iteration) {
    information.setZero();
    lie::Vector6d gradient = lie::Vector6d::Zero();
    chi2 = 0.0;
    largest = 0.0;
    const Eigen::Matrix3d& R = T.linear();
    for (const PointPair& pair : pairs) {
      const Eigen::Vector3d transformed = T * pair.p_source;
      const Eigen::Vector3d residual = pair.p_target - transformed;
      const auto weight = symmetric3::positive_definite_inverse(
          pair.covariance_target + R * pair.covariance_source * R.transpose());
      if (!weight) return std::nullopt;
      // J = [-I, X], X = [T p_s]_x, W = S^-1:
      //   J^T W J = [W, -W X; -(W X)^T, X^T W X],  J^T W r = [-W r; X^T W r].
      const Eigen::Matrix3d X = lie::skew(transformed);
      const Eigen::Matrix3d WX = *weight * X;
      const Eigen::Vector3d Wr = *weight * residual;
      information.topLeftCorner<3, 3>() += *weight;
      information.topRightCorner<3, 3>() -= WX;
      information.bottomLeftCorner<3, 3>() -= WX.transpose();
      information.bottomRightCorner<3, 3>() += X.transpose() * WX;
      gradient.head<3>() -= Wr;
      gradient.tail<3>() += X.transpose() * Wr;
      const double squared = residual.dot(Wr);
      chi2 += squared;
      largest = std::max(largest, squared);
    }
    if (iteration == gauss_newton_iterations) break;
    const Eigen::LDLT<lie::Matrix6d> ldlt(information);
    if (ldlt.info() != Eigen::Success) return std::nullopt;
    // Minimizes sum ||r + J eps||^2: eps = -(J^T W J)^-1 J^T W r.
    const lie::Vector6d step = -ldlt.solve(gradient);
    if (!step.allFinite()) return std::nullopt;
    T = lie::orthonormalized(lie::se3_exp(step) * T);
    if (step.norm() < 1e-12) {
      iteration = gauss_newton_iterations - 1;  // one more pass to evaluate at the solution
    }
  }

  // 3. Covariance: covariance intersection over the n correspondences, n (J^T W J)^-1, scaled by
  //    the residuals' excess over the 3n - 6 degrees of freedom.
  const Eigen::LLT<lie::Matrix6d> llt(information);
  if (llt.info() != Eigen::Success || !(llt.rcond() > 1e-9)) return std::nullopt;
  const auto n = static_cast<double>(pairs.size());
  const double degrees_of_freedom = std::max(1.0, 3.0 * n - 6.0);
  const double variance_factor = std::max(1.0, chi2 / degrees_of_freedom);
  RigidAlignment result;
  result.T_target_source = T;
  result.covariance = n * variance_factor * llt.solve(lie::Matrix6d::Identity());
  result.covariance = 0.5 * (result.covariance + result.covariance.transpose()).eval();
  result.chi2 = chi2;
  result.largest_residual = largest;
  return result;
}

lie::Matrix6d compose_covariance(const Eigen::Isometry3d& T_a_b,
                                 const lie::Matrix6d& covariance_a_b,
                                 const lie::Matrix6d& covariance_b_c) {
  const lie::Matrix6d adjoint = lie::adjoint(T_a_b);
  return covariance_a_b + adjoint * covariance_b_c * adjoint.transpose();
}

lie::Matrix6d inverse_covariance(const Eigen::Isometry3d& T, const lie::Matrix6d& covariance) {
  const lie::Matrix6d adjoint = lie::adjoint(T.inverse());
  return adjoint * covariance * adjoint.transpose();
}

}  // namespace concord::association
