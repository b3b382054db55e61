#pragma once
/// \file
/// Closed forms for symmetric positive-definite 3x3 matrices (an object's covariance): the
/// inverse and the quadratic form r^T S^-1 r without a general factorization. The filter's
/// consensus and the association's searches evaluate them hundreds of thousands of times a run,
/// where Eigen's LLT solve on a 3x3 costs several times the arithmetic.
///
/// Each reads its argument as symmetric, from its lower triangle, and refuses (nullopt) a matrix
/// that is not positive definite, or holds a NaN.

#include <Eigen/Core>
#include <array>
#include <optional>

namespace concord::symmetric3 {

/// A symmetric 3x3 matrix by its lower triangle, row by row: (0,0), (1,0), (2,0), (1,1), (2,1),
/// (2,2).
using Lower = std::array<double, 6>;

inline Lower lower_of(const Eigen::Matrix3d& M) {
  return {M(0, 0), M(1, 0), M(2, 0), M(1, 1), M(2, 1), M(2, 2)};
}

/// The lower triangle of A + B.
inline Lower lower_of_sum(const Eigen::Matrix3d& A, const Eigen::Matrix3d& B) {
  return {A(0, 0) + B(0, 0), A(1, 0) + B(1, 0), A(2, 0) + B(2, 0),
          A(1, 1) + B(1, 1), A(2, 1) + B(2, 1), A(2, 2) + B(2, 2)};
}

/// The inverse in closed form (the adjugate over the determinant), if the matrix is positive
/// definite (Sylvester: its leading principal minors are positive). Exactly symmetric.
std::optional<Eigen::Matrix3d> positive_definite_inverse(const Eigen::Matrix3d& P);

/// Whether the matrix is positive definite: the pivots of S = L diag(p) L^T are positive (what
/// a Cholesky factorization's success says, without one).
bool positive_definite(const Lower& S);

/// r^T S^-1 r through S = L diag(p) L^T in closed form; nullopt when a pivot p is not positive.
std::optional<double> inverse_quadratic(const Lower& S, const Eigen::Vector3d& r);

/// r^T (A + B)^-1 r.
inline std::optional<double> inverse_quadratic(const Eigen::Matrix3d& A, const Eigen::Matrix3d& B,
                                               const Eigen::Vector3d& r) {
  return inverse_quadratic(lower_of_sum(A, B), r);
}

}  // namespace concord::symmetric3
