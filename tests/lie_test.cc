#include "concord/estimator/lie.h"

#include <gtest/gtest.h>

#include <random>

namespace concord {
namespace {

lie::Vector6d random_twist(std::mt19937& random, double scale) {
  std::normal_distribution<double> normal(0.0, scale);
  lie::Vector6d xi;
  for (int i = 0; i < 6; ++i) xi(i) = normal(random);
  return xi;
}

TEST(Lie, SkewIsCrossProduct) {
  const Eigen::Vector3d a(1.0, -2.0, 0.5), b(0.3, 0.7, -1.1);
  EXPECT_TRUE((lie::skew(a) * b).isApprox(a.cross(b), 1e-14));
}

TEST(Lie, So3ExpIsARotationAndLogInvertsIt) {
  std::mt19937 random(1);
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::Vector3d phi = random_twist(random, 0.8).tail<3>();
    const Eigen::Matrix3d R = lie::so3_exp(phi);
    EXPECT_TRUE((R.transpose() * R).isIdentity(1e-12));
    EXPECT_NEAR(R.determinant(), 1.0, 1e-12);
    EXPECT_TRUE(lie::so3_log(R).isApprox(phi, 1e-9));
  }
  // Against Eigen's independent implementation.
  const Eigen::Vector3d phi(0.3, -0.2, 1.1);
  EXPECT_TRUE(lie::so3_exp(phi).isApprox(
      Eigen::AngleAxisd(phi.norm(), phi.normalized()).toRotationMatrix(), 1e-12));
  // Small angles take the series branch.
  const Eigen::Vector3d tiny(1e-10, -2e-10, 3e-10);
  EXPECT_TRUE(lie::so3_log(lie::so3_exp(tiny)).isApprox(tiny, 1e-6));
}

TEST(Lie, Se3ExpLogRoundTrip) {
  std::mt19937 random(2);
  for (int trial = 0; trial < 50; ++trial) {
    const lie::Vector6d xi = random_twist(random, 0.7);
    EXPECT_TRUE(lie::se3_log(lie::se3_exp(xi)).isApprox(xi, 1e-9)) << xi.transpose();
  }
}

TEST(Lie, Se3ExpMatchesMatrixExponentialSeries) {
  // exp of the 4x4 twist matrix by a long Taylor series, independent of the closed form.
  const lie::Vector6d xi = (lie::Vector6d() << 0.4, -0.3, 1.2, 0.2, -0.5, 0.35).finished();
  Eigen::Matrix4d twist = Eigen::Matrix4d::Zero();
  twist.topLeftCorner<3, 3>() = lie::skew(xi.tail<3>());
  twist.topRightCorner<3, 1>() = xi.head<3>();
  Eigen::Matrix4d sum = Eigen::Matrix4d::Identity(), term = Eigen::Matrix4d::Identity();
  for (int k = 1; k < 30; ++k) {
    term = term * twist / k;
    sum += term;
  }
  EXPECT_TRUE(lie::se3_exp(xi).matrix().isApprox(sum, 1e-12));
}

TEST(Lie, AdjointConjugatesTheExponential) {
  std::mt19937 random(3);
  for (int trial = 0; trial < 20; ++trial) {
    const Eigen::Isometry3d T = lie::se3_exp(random_twist(random, 1.0));
    const lie::Vector6d xi = random_twist(random, 0.3);
    const Eigen::Isometry3d lhs = T * lie::se3_exp(xi) * T.inverse();
    const Eigen::Isometry3d rhs = lie::se3_exp(lie::adjoint(T) * xi);
    EXPECT_TRUE(lhs.matrix().isApprox(rhs.matrix(), 1e-10));
  }
}

TEST(Lie, AdjointOfInverseIsInverseOfAdjoint) {
  std::mt19937 random(4);
  const Eigen::Isometry3d T = lie::se3_exp(random_twist(random, 1.0));
  EXPECT_TRUE((lie::adjoint(T.inverse()) * lie::adjoint(T)).isIdentity(1e-12));
}

TEST(Lie, LeftJacobianIsTheDerivativeOfExp) {
  // exp(phi + d) ~ exp(J_l(phi) d) exp(phi) for small d.
  const Eigen::Vector3d phi(0.5, -0.4, 0.9);
  const Eigen::Matrix3d J = lie::so3_left_jacobian(phi);
  const double h = 1e-6;
  for (int i = 0; i < 3; ++i) {
    const Eigen::Vector3d d = h * Eigen::Vector3d::Unit(i);
    const Eigen::Vector3d numeric =
        lie::so3_log(lie::so3_exp(phi + d) * lie::so3_exp(phi).transpose()) / h;
    EXPECT_TRUE(numeric.isApprox(J.col(i), 1e-5));
  }
}

TEST(Lie, OrthonormalizedRepairsDrift) {
  Eigen::Isometry3d T = lie::se3_exp((lie::Vector6d() << 1, 2, 3, 0.1, 0.2, 0.3).finished());
  T.linear() *= 1.001;
  const Eigen::Isometry3d fixed = lie::orthonormalized(T);
  EXPECT_TRUE((fixed.linear().transpose() * fixed.linear()).isIdentity(1e-12));
  EXPECT_TRUE(fixed.translation().isApprox(T.translation()));
}

}  // namespace
}  // namespace concord
