// The closed forms for symmetric positive-definite 3x3 matrices against Eigen's factorizations.
#include "concord/estimator/symmetric3.h"

#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <cmath>
#include <limits>
#include <random>

namespace concord {
namespace {

/// A random covariance with the given condition number: Q diag(1, sqrt(c), c) Q^T times a scale.
Eigen::Matrix3d random_covariance(std::mt19937& random, double condition, double scale) {
  std::normal_distribution<double> normal;
  Eigen::Matrix3d A;
  for (int k = 0; k < 9; ++k) A(k / 3, k % 3) = normal(random);
  const Eigen::Matrix3d Q = Eigen::HouseholderQR<Eigen::Matrix3d>(A).householderQ();
  const Eigen::Vector3d eigenvalues(1.0, std::sqrt(condition), condition);
  return scale * Q * eigenvalues.asDiagonal() * Q.transpose();
}

TEST(Symmetric3, TheInverseAndTheQuadraticFormAgreeWithCholesky) {
  std::mt19937 random(7);
  std::normal_distribution<double> normal;
  for (int trial = 0; trial < 200; ++trial) {
    const double condition = std::pow(10.0, trial % 7);  // up to 1e6
    const double scale = std::pow(10.0, (trial % 5) - 3);
    const Eigen::Matrix3d S = random_covariance(random, condition, scale);
    const Eigen::Vector3d r(normal(random), normal(random), normal(random));
    const Eigen::LLT<Eigen::Matrix3d> llt(S);
    ASSERT_EQ(llt.info(), Eigen::Success);
    const Eigen::Matrix3d expected_inverse = llt.solve(Eigen::Matrix3d::Identity());
    const double expected_quadratic = r.dot(llt.solve(r));

    const auto inverse = symmetric3::positive_definite_inverse(S);
    ASSERT_TRUE(inverse.has_value()) << "trial " << trial;
    // Relative to the inverse's size; the error grows with the condition number.
    const double tolerance = 1e-12 * condition * expected_inverse.norm();
    EXPECT_LT((*inverse - expected_inverse).norm(), tolerance) << "trial " << trial;
    const Eigen::Matrix3d asymmetry = *inverse - inverse->transpose();
    EXPECT_EQ(asymmetry.cwiseAbs().maxCoeff(), 0.0) << "exactly symmetric";

    const auto quadratic = symmetric3::inverse_quadratic(symmetric3::lower_of(S), r);
    ASSERT_TRUE(quadratic.has_value());
    EXPECT_NEAR(*quadratic, expected_quadratic, 1e-12 * condition * expected_quadratic);
    EXPECT_TRUE(symmetric3::positive_definite(symmetric3::lower_of(S))) << "trial " << trial;
    // The sum form reads A + B.
    const Eigen::Matrix3d half = 0.5 * S;
    const auto of_sum = symmetric3::inverse_quadratic(half, S - half, r);
    ASSERT_TRUE(of_sum.has_value());
    EXPECT_NEAR(*of_sum, expected_quadratic, 1e-12 * condition * expected_quadratic);
  }
}

TEST(Symmetric3, OnlyTheLowerTriangleIsRead) {
  Eigen::Matrix3d S;
  S << 4.0, 99.0, -99.0,  //
      1.0, 3.0, 99.0,     //
      0.5, -0.2, 2.0;
  const Eigen::Matrix3d symmetric = S.selfadjointView<Eigen::Lower>();
  const Eigen::Vector3d r(0.3, -1.0, 2.0);
  const auto inverse = symmetric3::positive_definite_inverse(S);
  ASSERT_TRUE(inverse.has_value());
  EXPECT_LT((*inverse * symmetric - Eigen::Matrix3d::Identity()).norm(), 1e-14);
  const auto quadratic = symmetric3::inverse_quadratic(symmetric3::lower_of(S), r);
  ASSERT_TRUE(quadratic.has_value());
  EXPECT_NEAR(*quadratic, r.dot(symmetric.llt().solve(r)), 1e-13);
}

TEST(Symmetric3, MatricesThatAreNotPositiveDefiniteAreRefused) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const Eigen::Vector3d r(1.0, 2.0, 3.0);
  Eigen::Matrix3d indefinite = Eigen::Vector3d(1.0, -1.0, 2.0).asDiagonal();
  Eigen::Matrix3d singular = Eigen::Matrix3d::Ones();  // rank 1
  Eigen::Matrix3d second_minor;                        // a > 0, a d - b^2 < 0
  second_minor << 1.0, 2.0, 0.0,                       //
      2.0, 1.0, 0.0,                                   //
      0.0, 0.0, 1.0;
  Eigen::Matrix3d with_nan = Eigen::Matrix3d::Identity();
  with_nan(2, 1) = nan;
  with_nan(1, 2) = nan;
  for (const Eigen::Matrix3d& S : {indefinite, singular, second_minor, with_nan,
                                   Eigen::Matrix3d(-Eigen::Matrix3d::Identity())}) {
    EXPECT_FALSE(symmetric3::positive_definite_inverse(S).has_value()) << S;
    EXPECT_FALSE(symmetric3::inverse_quadratic(symmetric3::lower_of(S), r).has_value()) << S;
    EXPECT_FALSE(symmetric3::positive_definite(symmetric3::lower_of(S))) << S;
    // As a Cholesky factorization says (which does not look for NaN).
    if (S.allFinite()) {
      EXPECT_NE(Eigen::LLT<Eigen::Matrix3d>(S.selfadjointView<Eigen::Lower>()).info(),
                Eigen::Success)
          << S;
    }
  }
}

}  // namespace
}  // namespace concord
