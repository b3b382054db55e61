#include "concord/estimator/updater_helper.h"

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <cmath>
#include <limits>

#include "concord/estimator/lie.h"
#include "concord/estimator/state_helper.h"

namespace concord {

namespace {

Eigen::Matrix<double, 2, 3> projection_jacobian(const Eigen::Vector3d& p) {
  const double inverse_z = 1.0 / p.z();
  Eigen::Matrix<double, 2, 3> J;
  J << inverse_z, 0.0, -p.x() * inverse_z * inverse_z, 0.0, inverse_z,
      -p.y() * inverse_z * inverse_z;
  return J;
}

/// Inverse of the standard normal CDF (Acklam's rational approximation, relative error below
/// 1.2e-9); the starting point of the chi-square quantile.
double normal_quantile(double p) {
  static constexpr double a[] = {-3.969683028665376e+01, 2.209460984245205e+02,
                                 -2.759285104469687e+02, 1.383577518672690e+02,
                                 -3.066479806614716e+01, 2.506628277459239e+00};
  static constexpr double b[] = {-5.447609879822406e+01, 1.615858368580409e+02,
                                 -1.556989798598866e+02, 6.680131188771972e+01,
                                 -1.328068155288572e+01};
  static constexpr double c[] = {-7.784894002430293e-03, -3.223964580411365e-01,
                                 -2.400758277161838e+00, -2.549732539343734e+00,
                                 4.374664141464968e+00,  2.938163982698783e+00};
  static constexpr double d[] = {7.784695709041462e-03, 3.224671290700398e-01,
                                 2.445134137142996e+00, 3.754408661907416e+00};
  constexpr double low = 0.02425;
  if (p < low) {
    const double q = std::sqrt(-2.0 * std::log(p));
    return (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
           ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0);
  }
  if (p > 1.0 - low) {
    const double q = std::sqrt(-2.0 * std::log(1.0 - p));
    return -(((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
           ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0);
  }
  const double q = p - 0.5;
  const double r = q * q;
  return (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q /
         (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0);
}

/// Regularized lower incomplete gamma function P(a, x) (Numerical Recipes: series for
/// x < a + 1, continued fraction otherwise).
double regularized_lower_gamma(double a, double x) {
  if (x <= 0.0) return 0.0;
  const double log_prefactor = a * std::log(x) - x - std::lgamma(a);
  if (x < a + 1.0) {
    double term = 1.0 / a, sum = term;
    for (int n = 1; n < 500 && std::abs(term) > 1e-16 * std::abs(sum); ++n) {
      term *= x / (a + n);
      sum += term;
    }
    return sum * std::exp(log_prefactor);
  }
  constexpr double tiny = 1e-300;
  double b = x + 1.0 - a, c = 1.0 / tiny, d = 1.0 / b, fraction = d;
  for (int i = 1; i < 500; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::abs(d) < tiny) d = tiny;
    c = b + an / c;
    if (std::abs(c) < tiny) c = tiny;
    d = 1.0 / d;
    const double delta = d * c;
    fraction *= delta;
    if (std::abs(delta - 1.0) < 1e-16) break;
  }
  return 1.0 - std::exp(log_prefactor) * fraction;
}

}  // namespace

std::optional<StereoProjection> UpdaterHelper::project(const StereoCamera& camera,
                                                       const Eigen::Isometry3d& T_world_body,
                                                       const Eigen::Vector3d& p_world,
                                                       double min_depth) {
  const Eigen::Matrix3d R_world_body = T_world_body.linear();
  const Eigen::Vector3d p_body = R_world_body.transpose() * (p_world - T_world_body.translation());
  const Eigen::Isometry3d T_cam1_body = camera.T_cam1_body();
  const Eigen::Vector3d p_cam0 = camera.T_cam0_body * p_body;
  const Eigen::Vector3d p_cam1 = T_cam1_body * p_body;
  if (p_cam0.z() < min_depth || p_cam1.z() < min_depth) return std::nullopt;

  // d p_body / d [rho; phi] = [-I, [p_body]_x] for T = T_hat exp(eps^); d p_body / d p_w = R^T.
  Eigen::Matrix<double, 3, 6> body_wrt_pose;
  body_wrt_pose.leftCols<3>() = -Eigen::Matrix3d::Identity();
  body_wrt_pose.rightCols<3>() = lie::skew(p_body);

  StereoProjection out;
  out.depth_left = p_cam0.z();
  out.depth_right = p_cam1.z();
  out.xy << p_cam0.x() / p_cam0.z(), p_cam0.y() / p_cam0.z(), p_cam1.x() / p_cam1.z(),
      p_cam1.y() / p_cam1.z();
  const Eigen::Matrix<double, 2, 3> J_left =
      projection_jacobian(p_cam0) * camera.T_cam0_body.linear();
  const Eigen::Matrix<double, 2, 3> J_right = projection_jacobian(p_cam1) * T_cam1_body.linear();
  out.jacobian_pose.topRows<2>() = J_left * body_wrt_pose;
  out.jacobian_pose.bottomRows<2>() = J_right * body_wrt_pose;
  out.jacobian_point.topRows<2>() = J_left * R_world_body.transpose();
  out.jacobian_point.bottomRows<2>() = J_right * R_world_body.transpose();
  return out;
}

std::optional<Eigen::Vector3d> UpdaterHelper::triangulate(
    const StereoCamera& camera, const std::vector<Eigen::Isometry3d>& T_world_bodies,
    const std::vector<Eigen::Vector4d>& observations) {
  if (T_world_bodies.empty() || T_world_bodies.size() != observations.size()) return std::nullopt;

  // 1. Linear triangulation: for each camera with P = [R_cw | t_cw], x (P3 X) - P1 X = 0 and
  //    y (P3 X) - P2 X = 0, stacked over both cameras of every frame.
  const std::size_t rows = 4 * observations.size();
  Eigen::MatrixXd A(rows, 3);
  Eigen::VectorXd b(rows);
  const Eigen::Isometry3d T_cam1_body = camera.T_cam1_body();
  for (std::size_t i = 0; i < observations.size(); ++i) {
    const Eigen::Isometry3d T_body_world = T_world_bodies[i].inverse();
    const Eigen::Isometry3d T_cams_world[2] = {camera.T_cam0_body * T_body_world,
                                               T_cam1_body * T_body_world};
    for (int side = 0; side < 2; ++side) {
      const Eigen::Matrix3d R = T_cams_world[side].linear();
      const Eigen::Vector3d t = T_cams_world[side].translation();
      const double x = observations[i](2 * side);
      const double y = observations[i](2 * side + 1);
      const std::size_t row = 4 * i + 2 * side;
      A.row(row) = x * R.row(2) - R.row(0);
      b(row) = t.x() - x * t.z();
      A.row(row + 1) = y * R.row(2) - R.row(1);
      b(row + 1) = t.y() - y * t.z();
    }
  }
  const Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(A);
  if (qr.rank() < 3) return std::nullopt;
  Eigen::Vector3d p_world = qr.solve(b);

  // 2. Gauss-Newton on the reprojection error (Levenberg-Marquardt damped).
  double lambda = 1e-6;
  double cost = std::numeric_limits<double>::infinity();
  for (int iteration = 0; iteration < 10; ++iteration) {
    Eigen::Matrix3d normal = Eigen::Matrix3d::Zero();
    Eigen::Vector3d gradient = Eigen::Vector3d::Zero();
    double new_cost = 0.0;
    bool valid = true;
    for (std::size_t i = 0; i < observations.size(); ++i) {
      const auto projection = project(camera, T_world_bodies[i], p_world);
      if (!projection) {
        valid = false;
        break;
      }
      const Eigen::Vector4d residual = observations[i] - projection->xy;
      normal += projection->jacobian_point.transpose() * projection->jacobian_point;
      gradient += projection->jacobian_point.transpose() * residual;
      new_cost += residual.squaredNorm();
    }
    if (!valid) return std::nullopt;
    if (new_cost > cost) break;
    cost = new_cost;
    normal.diagonal() *= (1.0 + lambda);
    const Eigen::Vector3d step = normal.ldlt().solve(gradient);
    if (!step.allFinite()) return std::nullopt;
    p_world += step;
    if (step.norm() < 1e-9 * (1.0 + p_world.norm())) break;
  }
  for (std::size_t i = 0; i < observations.size(); ++i) {
    if (!project(camera, T_world_bodies[i], p_world)) return std::nullopt;
  }
  return p_world;
}

double UpdaterHelper::rms_reprojection_error(const StereoCamera& camera,
                                             const std::vector<Eigen::Isometry3d>& T_world_bodies,
                                             const std::vector<Eigen::Vector4d>& observations,
                                             const Eigen::Vector3d& p_world) {
  double sum = 0.0;
  for (std::size_t i = 0; i < observations.size(); ++i) {
    const auto projection = project(camera, T_world_bodies[i], p_world);
    if (!projection) return std::numeric_limits<double>::infinity();
    sum += (observations[i] - projection->xy).squaredNorm();
  }
  return std::sqrt(sum / (4.0 * static_cast<double>(observations.size())));
}

std::optional<LinearizedTrack> UpdaterHelper::linearize(const State& state,
                                                        const StereoCamera& camera,
                                                        const std::vector<TrackObservation>& track,
                                                        const Eigen::Vector3d& p_world,
                                                        int landmark_slot) {
  const Eigen::Index rows = 4 * static_cast<Eigen::Index>(track.size());
  LinearizedTrack out;
  out.H_state = Eigen::MatrixXd::Zero(rows, state.dimension());
  out.H_point.resize(rows, 3);
  out.residual.resize(rows);
  const int newest_frame = state.newest_pose().frame;
  for (std::size_t i = 0; i < track.size(); ++i) {
    const int slot = state.pose_slot(track[i].frame);
    if (slot < 0) return std::nullopt;
    const auto projection = project(camera, state.poses[slot].T_world_body, p_world);
    if (!projection) return std::nullopt;
    const Eigen::Index row = 4 * static_cast<Eigen::Index>(i);
    out.H_state.block<4, 6>(row, state.pose_index(slot)) = projection->jacobian_pose;
    out.H_point.block<4, 3>(row, 0) = projection->jacobian_point;
    out.residual.segment<4>(row) = track[i].xy - projection->xy;
    if (track[i].frame == newest_frame) out.newest_frame_row = static_cast<int>(row);
  }
  if (landmark_slot >= 0) {
    const int index = state.landmark_index(landmark_slot);
    out.H_state.middleCols<3>(index) = out.H_point;
  }
  return out;
}

void UpdaterHelper::nullspace_project_inplace(Eigen::MatrixXd& H_state, Eigen::MatrixXd& H_point,
                                              Eigen::VectorXd& residual, Eigen::MatrixXd* extra) {
  // Q^T H_point = [R; 0]: the last rows - 3 rows of Q^T span the left null space of H_point.
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(H_point);
  const Eigen::Index rows = H_point.rows();
  const auto Qt = qr.householderQ().transpose();
  H_state = (Qt * H_state).bottomRows(rows - 3).eval();
  residual = (Qt * residual).tail(rows - 3).eval();
  if (extra != nullptr) *extra = (Qt * (*extra)).bottomRows(rows - 3).eval();
  H_point = Eigen::MatrixXd::Zero(rows - 3, 3);
}

void UpdaterHelper::measurement_compress_inplace(Eigen::MatrixXd& H, Eigen::VectorXd& residual,
                                                 Eigen::MatrixXd* extra) {
  const std::vector<int> columns = StateHelper::nonzero_columns(H);
  const Eigen::Index k = static_cast<Eigen::Index>(columns.size());
  if (H.rows() <= k) return;
  const Eigen::MatrixXd compact = H(Eigen::all, columns);
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(compact);
  const auto Qt = qr.householderQ().transpose();
  const Eigen::MatrixXd compact_out = (Qt * compact).topRows(k);
  residual = (Qt * residual).head(k).eval();
  if (extra != nullptr) *extra = (Qt * (*extra)).topRows(k).eval();
  H = Eigen::MatrixXd::Zero(k, H.cols());
  H(Eigen::all, columns) = compact_out;
}

double UpdaterHelper::chi2_quantile(double probability, int dof) {
  if (dof <= 0 || probability <= 0.0) return 0.0;
  if (probability >= 1.0) return std::numeric_limits<double>::infinity();
  // Start from Wilson-Hilferty ((X/k)^(1/3) is nearly normal with mean 1 - 2/(9k), variance
  // 2/(9k)), then polish with Newton steps on the exact CDF P(k/2, x/2).
  const double k = dof;
  const double h = 2.0 / (9.0 * k);
  const double cube = std::max(1.0 - h + normal_quantile(probability) * std::sqrt(h), 0.1);
  double x = k * cube * cube * cube;
  for (int iteration = 0; iteration < 50; ++iteration) {
    const double error = regularized_lower_gamma(0.5 * k, 0.5 * x) - probability;
    // Chi-square density at x.
    const double density = std::exp((0.5 * k - 1.0) * std::log(x) - 0.5 * x -
                                    0.5 * k * std::log(2.0) - std::lgamma(0.5 * k));
    const double step = error / density;
    x = std::max(x - step, 0.5 * x);
    if (std::abs(step) < 1e-10 * x) break;
  }
  return x;
}

}  // namespace concord
