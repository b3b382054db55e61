#include "concord/estimator/updater_helper.h"

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <array>
#include <boost/math/distributions/chi_squared.hpp>
#include <cassert>
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

}  // namespace

Eigen::Matrix<double, 4, 6> UpdaterHelper::pose_jacobian(
    const Eigen::Matrix<double, 4, 3>& jacobian_point, const Eigen::Vector3d& p_linearization) {
  Eigen::Matrix<double, 4, 6> jacobian;
  jacobian.leftCols<3>() = -jacobian_point;
  jacobian.rightCols<3>() = jacobian_point * lie::skew(p_linearization);
  return jacobian;
}

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


  StereoProjection out;
  out.depth_left = p_cam0.z();
  out.depth_right = p_cam1.z();
  out.xy << p_cam0.x() / p_cam0.z(), p_cam0.y() / p_cam0.z(), p_cam1.x() / p_cam1.z(),
      p_cam1.y() / p_cam1.z();
  const Eigen::Matrix<double, 2, 3> J_left =
      projection_jacobian(p_cam0) * camera.T_cam0_body.linear();
  const Eigen::Matrix<double, 2, 3> J_right = projection_jacobian(p_cam1) * T_cam1_body.linear();
  // d p_body / d p_w = R^T; d p_body / d [rho; phi] = R^T [-I, [p_w]_x] for T = exp(eps^) T_hat.
  out.jacobian_point.topRows<2>() = J_left * R_world_body.transpose();
  out.jacobian_point.bottomRows<2>() = J_right * R_world_body.transpose();
  out.jacobian_pose = pose_jacobian(out.jacobian_point, p_world);
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
  // In-state objects: pose Jacobians at the landmark's first estimate (see ObjectLandmark).
  const Eigen::Vector3d& p_linearization =
      landmark_slot >= 0 ? state.landmarks[landmark_slot].p_linearization : p_world;
  const Eigen::Index rows = 4 * static_cast<Eigen::Index>(track.size());
  LinearizedTrack out;
  out.H_state = Eigen::MatrixXd::Zero(rows, state.dimension());
  out.H_point.resize(rows, 3);
  out.residual.resize(rows);
  const int newest_frame = state.newest_pose().frame;
  // With a disparity offset state d: the right image's x is predicted as x_r + d / fx.
  const bool has_offset = state.has_disparity_offset;
  const double offset_x = has_offset ? state.disparity_offset / camera.K(0, 0) : 0.0;
  for (std::size_t i = 0; i < track.size(); ++i) {
    const int slot = state.pose_slot(track[i].frame);
    if (slot < 0) return std::nullopt;
    const auto projection = project(camera, state.poses[slot].T_world_body, p_world);
    if (!projection) return std::nullopt;
    const Eigen::Index row = 4 * static_cast<Eigen::Index>(i);
    out.H_state.block<4, 6>(row, state.pose_index(slot)) =
        landmark_slot >= 0 ? pose_jacobian(projection->jacobian_point, p_linearization)
                           : projection->jacobian_pose;
    out.H_point.block<4, 3>(row, 0) = projection->jacobian_point;
    out.residual.segment<4>(row) = track[i].xy - projection->xy;
    if (has_offset) {
      out.residual(row + 2) -= offset_x;
      out.H_state(row + 2, state.disparity_offset_index()) = 1.0 / camera.K(0, 0);
    }
    if (track[i].frame == newest_frame) out.newest_frame_row = static_cast<int>(row);
  }
  if (landmark_slot >= 0) {
    const int index = state.landmark_index(landmark_slot);
    out.H_state.middleCols<3>(index) = out.H_point;
  }
  return out;
}

void UpdaterHelper::linearize_level(const State& state, const Eigen::Vector3d& level_axis,
                                    Eigen::MatrixXd& H, Eigen::VectorXd& residual) {
  // The body's level axis u, seen in the world as g = R u, measures the world's up axis w. With
  // the left perturbation R = exp(phi^) R_hat, g = g_hat + phi x g_hat, so the rows are
  // -[a b]^T g_hat^ on phi and -[a b]^T dw/dt on the tilt.
  const WorldUp& world_up = state.world_up;
  const Eigen::Vector3d w = world_up.direction();
  const Eigen::Vector3d a = w.unitOrthogonal();
  Eigen::Matrix<double, 2, 3> across;
  across.row(0) = a.transpose();
  across.row(1) = w.cross(a).transpose();
  const int slot = state.num_poses() - 1;
  const Eigen::Vector3d g = state.newest_pose().T_world_body.linear() * level_axis;
  H = Eigen::MatrixXd::Zero(2, state.dimension());
  H.block<2, 3>(0, state.pose_index(slot) + 3) = -across * lie::skew(g);
  H.block<2, 2>(0, state.world_up_index()) = -across * world_up.jacobian();
  residual = -across * g;  // across * w, which is 0, minus the prediction
}

Eigen::Vector4d UpdaterHelper::without_disparity_offset(const State& state,
                                                        const StereoCamera& camera,
                                                        const Eigen::Vector4d& xy) {
  if (!state.has_disparity_offset) return xy;
  Eigen::Vector4d corrected = xy;
  corrected(2) -= state.disparity_offset / camera.K(0, 0);
  return corrected;
}

Eigen::Matrix4d UpdaterHelper::observation_covariance(const StereoNoise& noise,
                                                     const StereoCamera& camera) {
  // (u_left, u_right) = c + (d/2, -d/2) with c ~ N(0, horizontal^2), d ~ N(0, disparity^2);
  // likewise vertically. Then to normalized units.
  const auto pair = [](double common, double difference) {
    const double a = common * common, b = 0.25 * difference * difference;
    return Eigen::Matrix2d{{a + b, a - b}, {a - b, a + b}};
  };
  const Eigen::Matrix2d horizontal = pair(noise.horizontal, noise.disparity) /
                                     (camera.K(0, 0) * camera.K(0, 0));
  const Eigen::Matrix2d vertical = pair(noise.vertical, noise.vertical_disparity) /
                                   (camera.K(1, 1) * camera.K(1, 1));
  Eigen::Matrix4d covariance = Eigen::Matrix4d::Zero();
  for (int i = 0; i < 2; ++i) {
    for (int j = 0; j < 2; ++j) {
      covariance(2 * i, 2 * j) = horizontal(i, j);
      covariance(2 * i + 1, 2 * j + 1) = vertical(i, j);
    }
  }
  return covariance;
}

Eigen::Matrix4d UpdaterHelper::first_estimate_noise(
    const Eigen::Matrix<double, 4, 3>& jacobian_point, const Eigen::Vector3d& p_linearization,
    const Eigen::Vector3d& p_world, const Eigen::Matrix3d& rotation_covariance) {
  const Eigen::Matrix<double, 4, 3> A = jacobian_point * lie::skew(p_linearization - p_world);
  const Eigen::Matrix4d noise = A * rotation_covariance * A.transpose();
  return 0.5 * (noise + noise.transpose());
}

Eigen::Matrix4d UpdaterHelper::whitening(const Eigen::Matrix4d& covariance) {
  const Eigen::LLT<Eigen::Matrix4d> llt(covariance);
  assert(llt.info() == Eigen::Success);
  return llt.matrixL().solve(Eigen::Matrix4d::Identity());
}

void UpdaterHelper::whiten_inplace(LinearizedTrack& track, const Eigen::Matrix4d& whitening,
                                   Eigen::MatrixXd* extra) {
  for (Eigen::Index row = 0; row + 4 <= track.residual.size(); row += 4) {
    track.H_state.middleRows<4>(row) = (whitening * track.H_state.middleRows<4>(row)).eval();
    track.H_point.middleRows<4>(row) = (whitening * track.H_point.middleRows<4>(row)).eval();
    track.residual.segment<4>(row) = (whitening * track.residual.segment<4>(row)).eval();
    if (extra != nullptr) extra->middleRows<4>(row) = (whitening * extra->middleRows<4>(row)).eval();
  }
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
  // The gates ask for a handful of (probability, dof) pairs thousands of times a second, and each
  // quantile is an iterative inversion of the incomplete gamma function (about 1.5 % of a
  // 15-robot replay): the last few answers are kept, per thread.
  struct Answer {
    double probability = 0.0;
    int dof = 0;  // 0: empty (dof > 0 here)
    double quantile = 0.0;
  };
  thread_local std::array<Answer, 8> answers{};
  thread_local std::size_t next = 0;
  for (const Answer& answer : answers) {
    if (answer.dof == dof && answer.probability == probability) return answer.quantile;
  }
  const double quantile =
      boost::math::quantile(boost::math::chi_squared(static_cast<double>(dof)), probability);
  answers[next] = {probability, dof, quantile};
  next = (next + 1) % answers.size();
  return quantile;
}

}  // namespace concord
