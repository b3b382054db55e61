#include "concord/estimator/propagator.h"

#include "concord/estimator/lie.h"
#include "concord/estimator/state_helper.h"

namespace concord {

Propagator::Propagator(const EstimatorOptions& options) : window_size_(options.window_size) {
  odometry_noise_.setZero();
  odometry_noise_.diagonal().head<3>().setConstant(options.odometry_translation_sigma *
                                                   options.odometry_translation_sigma);
  odometry_noise_.diagonal().tail<3>().setConstant(options.odometry_rotation_sigma *
                                                   options.odometry_rotation_sigma);
}

void Propagator::propagate(State& state, const Eigen::Isometry3d& T_previous_current, int frame,
                           const Eigen::Matrix<double, 6, 6>* noise_override) const {
  // 1. Marginalize the oldest pose when the window is full (the selection matrix A of eq. 23).
  if (state.num_poses() >= window_size_) StateHelper::remove_oldest_pose(state);

  // 2. Mean: T_new = T_newest * dT (eq. 22).
  const int newest = state.pose_index(state.num_poses() - 1);
  const Eigen::Isometry3d T_world_new =
      lie::orthonormalized(state.newest_pose().T_world_body * T_previous_current);
  // With left perturbations, exp(eps_new^) T_new = exp(eps^) T_newest dT exp(-w^) gives
  // eps_new = eps - Ad(T_new) w: the error carries over unchanged (eq. 23's J_t becomes the
  // identity in this chart) and the odometry noise enters rotated into the world frame.
  const lie::Matrix6d adjoint_new = lie::adjoint(T_world_new);
  const lie::Matrix6d& W = noise_override != nullptr ? *noise_override : odometry_noise_;
  const lie::Matrix6d noise = adjoint_new * W * adjoint_new.transpose();

  // 3. Covariance: insert the new pose block after the poses, before the landmarks:
  //    rows P[newest, :], block P_newest + Ad W Ad^T (eq. 23).
  const Eigen::MatrixXd& P = state.covariance;
  const int n = state.dimension();
  const int poses = state.pose_block_size();
  const int landmarks = n - poses;
  const Eigen::MatrixXd new_rows = P.middleRows(newest, 6);  // 6 x n
  Eigen::MatrixXd propagated(n + 6, n + 6);
  propagated.topLeftCorner(poses, poses) = P.topLeftCorner(poses, poses);
  propagated.bottomRightCorner(landmarks, landmarks) = P.bottomRightCorner(landmarks, landmarks);
  propagated.block(0, poses + 6, poses, landmarks) = P.topRightCorner(poses, landmarks);
  propagated.block(poses + 6, 0, landmarks, poses) = P.bottomLeftCorner(landmarks, poses);
  propagated.block(poses, 0, 6, poses) = new_rows.leftCols(poses);
  propagated.block(0, poses, poses, 6) = new_rows.leftCols(poses).transpose();
  propagated.block(poses, poses + 6, 6, landmarks) = new_rows.rightCols(landmarks);
  propagated.block(poses + 6, poses, landmarks, 6) = new_rows.rightCols(landmarks).transpose();
  Eigen::Matrix<double, 6, 6> block = new_rows.middleCols<6>(newest) + noise;
  propagated.block<6, 6>(poses, poses) = 0.5 * (block + block.transpose());
  state.covariance = std::move(propagated);
  state.poses.push_back({frame, T_world_new});
}

}  // namespace concord
