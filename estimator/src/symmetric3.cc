#include "concord/estimator/symmetric3.h"

namespace concord::symmetric3 {

std::optional<Eigen::Matrix3d> positive_definite_inverse(const Eigen::Matrix3d& P) {
  const double a = P(0, 0), b = P(1, 0), c = P(2, 0), d = P(1, 1), e = P(2, 1), f = P(2, 2);
  const double minor2 = a * d - b * b;
  const double c00 = d * f - e * e, c10 = c * e - b * f, c20 = b * e - c * d;
  const double determinant = a * c00 + b * c10 + c * c20;
  if (!(a > 0.0 && minor2 > 0.0 && determinant > 0.0)) return std::nullopt;
  const double scale = 1.0 / determinant;
  const double c11 = a * f - c * c, c21 = b * c - a * e;
  Eigen::Matrix3d inverse;
  inverse << c00, c10, c20,  //
      c10, c11, c21,         //
      c20, c21, minor2;
  inverse *= scale;
  // The compiler may contract a cofactor into a fused multiply-add in one of its two uses and
  // not in the other (x86-64-v3): the upper triangle is copied from the lower one.
  inverse(0, 1) = inverse(1, 0);
  inverse(0, 2) = inverse(2, 0);
  inverse(1, 2) = inverse(2, 1);
  return inverse;
}

namespace {

/// S = L diag(p) L^T with a unit lower-triangular L; nullopt when a pivot is not positive (or NaN).
struct Ldl {
  double l10, l20, l21, p0, p1, p2;
};

std::optional<Ldl> factor(const Lower& S) {
  const auto [s00, s10, s20, s11, s21, s22] = S;
  const double p0 = s00;
  if (!(p0 > 0.0)) return std::nullopt;
  const double l10 = s10 / p0, l20 = s20 / p0;
  const double p1 = s11 - l10 * s10;
  if (!(p1 > 0.0)) return std::nullopt;
  const double l21 = (s21 - l20 * s10) / p1;
  const double p2 = s22 - l20 * s20 - l21 * l21 * p1;
  if (!(p2 > 0.0)) return std::nullopt;
  return Ldl{l10, l20, l21, p0, p1, p2};
}

}  // namespace

bool positive_definite(const Lower& S) { return factor(S).has_value(); }

std::optional<double> inverse_quadratic(const Lower& S, const Eigen::Vector3d& r) {
  const std::optional<Ldl> f = factor(S);
  if (!f) return std::nullopt;
  const double y0 = r(0), y1 = r(1) - f->l10 * y0, y2 = r(2) - f->l20 * y0 - f->l21 * y1;
  return y0 * y0 / f->p0 + y1 * y1 / f->p1 + y2 * y2 / f->p2;
}

}  // namespace concord::symmetric3
