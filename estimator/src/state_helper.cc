#include "concord/estimator/state_helper.h"

#include <Eigen/Cholesky>
#include <stdexcept>
#include <string>

#include "concord/estimator/lie.h"
#include "concord/estimator/pose_conditioning.h"

namespace concord {

namespace {

/// P H^T using only the non-zero columns of H: n x m in O(n * k * m).
Eigen::MatrixXd covariance_times_jacobian_transpose(const Eigen::MatrixXd& P,
                                                    const Eigen::MatrixXd& H,
                                                    const std::vector<int>& columns) {
  return P(Eigen::all, columns) * H(Eigen::all, columns).transpose();
}

/// The covariance indices of the archived objects (Schmidt consider states), ascending.
std::vector<int> archived_indices(const State& state) {
  std::vector<int> indices;
  for (int slot = 0; slot < state.num_landmarks(); ++slot) {
    if (!state.landmarks[slot].archived) continue;
    for (int k = 0; k < 3; ++k) indices.push_back(state.landmark_index(slot) + k);
  }
  return indices;
}

/// 0 .. n-1 without the ascending `indices`.
std::vector<int> complement(const std::vector<int>& indices, int n) {
  std::vector<int> out;
  out.reserve(static_cast<std::size_t>(n) - indices.size());
  auto next = indices.begin();
  for (int i = 0; i < n; ++i) {
    if (next != indices.end() && *next == i) {
      ++next;
    } else {
      out.push_back(i);
    }
  }
  return out;
}

}  // namespace

void StateHelper::apply_correction(State& state,
                                   const Eigen::Ref<const Eigen::VectorXd>& correction) {
  for (int slot = 0; slot < state.num_poses(); ++slot) {
    auto& pose = state.poses[slot].T_world_body;
    pose = lie::orthonormalized(
        lie::se3_exp(correction.segment<State::kPoseDim>(state.pose_index(slot))) * pose);
  }
  for (int slot = 0; slot < state.num_landmarks(); ++slot) {
    state.landmarks[slot].p_world += correction.segment<3>(state.landmark_index(slot));
  }
  if (state.has_disparity_offset) {
    state.disparity_offset += correction(state.disparity_offset_index());
  }
  if (state.has_world_up) state.world_up.tilt += correction.segment<2>(state.world_up_index());
}

bool StateHelper::update(State& state, const Eigen::MatrixXd& H, const Eigen::VectorXd& residual,
                         const Eigen::MatrixXd& noise, const Eigen::MatrixXd* correlation) {
  if (H.rows() == 0) return true;
  Eigen::MatrixXd& P = state.covariance;
  const std::vector<int> columns = nonzero_columns(H);

  // 1. U = P H^T + S and the innovation covariance H P H^T + V + H S + S^T H^T (eq. 26-27).
  Eigen::MatrixXd U = covariance_times_jacobian_transpose(P, H, columns);
  Eigen::MatrixXd innovation = H(Eigen::all, columns) * U(columns, Eigen::all) + noise;
  if (correlation != nullptr) {
    const Eigen::MatrixXd HS = H * (*correlation);
    innovation += HS + HS.transpose();
    U += *correlation;
  }
  const Eigen::LLT<Eigen::MatrixXd> llt(innovation);
  if (llt.info() != Eigen::Success) return false;

  // 2. Correction K r with K = U innovation^-1 (eq. 26, 28).
  Eigen::VectorXd correction = U * llt.solve(residual);

  // 3. P <- P - U innovation^-1 U^T = P - W^T W with W = L^-1 U^T (eq. 66), on one triangle.
  const Eigen::MatrixXd W = llt.matrixL().solve(U.transpose());
  const std::vector<int> held = archived_indices(state);
  if (held.empty()) {
    P.selfadjointView<Eigen::Lower>().rankUpdate(W.transpose(), -1.0);
    P.triangularView<Eigen::StrictlyUpper>() = P.transpose();
  } else {
    // Schmidt update: archived objects are consider states, their gain rows zero. With K_s that
    // gain, the Joseph form P - K_s H P - P H^T K_s^T + K_s S K_s^T is P - W^T W everywhere
    // except the archived x archived block, which keeps its value: their estimates do not move,
    // and their cross-covariances with the active state follow its update (exact without
    // correlated noise; with it, the same rule). Only the active rows are formed.
    const std::vector<int> active = complement(held, state.dimension());
    const Eigen::MatrixXd reduction = W(Eigen::all, active).transpose() * W;  // active x n
    P(active, Eigen::all) -= reduction;
    P(held, active) = P(active, held).transpose();
    correction(held).setZero();
  }

  apply_correction(state, correction);
  return true;
}

double StateHelper::mahalanobis_squared(const State& state, const Eigen::MatrixXd& H,
                                        const Eigen::VectorXd& residual,
                                        const Eigen::MatrixXd& noise,
                                        const Eigen::MatrixXd* correlation) {
  const std::vector<int> columns = nonzero_columns(H);
  const Eigen::MatrixXd Hc = H(Eigen::all, columns);
  Eigen::MatrixXd innovation = Hc * state.covariance(columns, columns) * Hc.transpose() + noise;
  if (correlation != nullptr) {
    const Eigen::MatrixXd HS = H * (*correlation);
    innovation += HS + HS.transpose();
  }
  const Eigen::LLT<Eigen::MatrixXd> llt(innovation);
  if (llt.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
  return residual.dot(llt.solve(residual));
}

void StateHelper::augment_landmark(State& state, LandmarkId id, const Eigen::Vector3d& p_world,
                                   const Eigen::Vector3d& p_linearization, int frame,
                                   const Eigen::MatrixXd& H_state1,
                                   const Eigen::Matrix3d& R1, const Eigen::Matrix3d& noise1) {
  const int n = state.dimension();
  Eigen::MatrixXd& P = state.covariance;
  const std::vector<int> columns = nonzero_columns(H_state1);
  const Eigen::MatrixXd PHt = covariance_times_jacobian_transpose(P, H_state1, columns);  // n x 3
  const Eigen::Matrix3d R1_inverse = R1.inverse();

  // eq. (30): Sigma_sp = -Sigma H1^T R1^-T,  Sigma_p = R1^-1 (H1 Sigma H1^T + V1) R1^-T.
  const Eigen::MatrixXd cross = -PHt * R1_inverse.transpose();
  const Eigen::Matrix3d H1PH1t = H_state1(Eigen::all, columns) * PHt(columns, Eigen::all);
  Eigen::Matrix3d landmark_covariance = R1_inverse * (H1PH1t + noise1) * R1_inverse.transpose();
  landmark_covariance = 0.5 * (landmark_covariance + landmark_covariance.transpose()).eval();

  P.conservativeResize(n + 3, n + 3);
  P.block(0, n, n, 3) = cross;
  P.block(n, 0, 3, n) = cross.transpose();
  P.block<3, 3>(n, n) = landmark_covariance;
  ObjectLandmark landmark;
  landmark.id = id;
  landmark.p_world = p_world;
  landmark.last_observed_frame = frame;
  landmark.p_linearization = p_linearization;
  state.landmarks.push_back(std::move(landmark));
  state.rebuild_landmark_index();
}

void StateHelper::remove_landmarks(State& state, const std::vector<int>& slots) {
  if (slots.empty()) return;
  std::vector<bool> removed(state.num_landmarks(), false);
  for (int slot : slots) removed[slot] = true;
  std::vector<int> keep;
  keep.reserve(state.dimension());
  for (int i = 0; i < state.pose_block_size() + state.calibration_dim(); ++i) keep.push_back(i);
  std::vector<ObjectLandmark> kept_landmarks;
  for (int slot = 0; slot < state.num_landmarks(); ++slot) {
    if (removed[slot]) continue;
    kept_landmarks.push_back(state.landmarks[slot]);
    for (int k = 0; k < 3; ++k) keep.push_back(state.landmark_index(slot) + k);
  }
  state.covariance = state.covariance(keep, keep).eval();
  state.landmarks = std::move(kept_landmarks);
  state.rebuild_landmark_index();
}

void StateHelper::remove_oldest_pose(State& state) {
  const int n = state.dimension();
  state.covariance = state.covariance.bottomRightCorner(n - 6, n - 6).eval();
  state.poses.pop_front();
}

std::vector<int> StateHelper::nonzero_columns(const Eigen::MatrixXd& H) {
  std::vector<int> columns;
  for (Eigen::Index c = 0; c < H.cols(); ++c) {
    if (!H.col(c).isZero(0.0)) columns.push_back(static_cast<int>(c));
  }
  return columns;
}

void StateHelper::reanchor(State& state, const Eigen::Isometry3d& T_new_old,
                           const lie::Matrix6d& covariance, int correlated_slot,
                           const lie::Matrix6d& independent) {
  if (correlated_slot >= state.num_poses()) {
    throw std::invalid_argument("StateHelper::reanchor: no pose slot " +
                                std::to_string(correlated_slot));
  }
  const Eigen::Matrix3d& R = T_new_old.linear();
  const lie::Matrix6d adjoint = lie::adjoint(T_new_old);
  // 1. Means.
  for (PoseClone& pose : state.poses) {
    pose.T_world_body = lie::orthonormalized(T_new_old * pose.T_world_body);
  }
  for (ObjectLandmark& landmark : state.landmarks) {
    if (landmark.detection_offset) {
      // An image offset has no frame; a displacement is a direction: it turns.
      if (landmark.displacement) landmark.p_world = R * landmark.p_world;
      continue;
    }
    landmark.p_world = T_new_old * landmark.p_world;
    landmark.p_linearization = T_new_old * landmark.p_linearization;
  }
  // The world's up axis turns with the frame, its basis with it: the tilt keeps its value.
  state.world_up.reference = R * state.world_up.reference;
  state.world_up.basis = R * state.world_up.basis;
  // 2. Joint covariance: P <- G P G^T + J covariance J^T, G block diagonal (identity on the
  //    calibration).
  const int n = state.dimension();
  Eigen::MatrixXd& P = state.covariance;
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(n, 6);  // the disparity offset does not move
  if (state.has_world_up) {
    // w' = exp(phi_e^) R w: the transform's rotation error turns the up axis, w' + phi_e x w',
    // which the tilt takes through the pseudo-inverse of dw'/dt.
    const Eigen::Matrix<double, 3, 2> jacobian = state.world_up.jacobian();
    const Eigen::Matrix2d normal = jacobian.transpose() * jacobian;
    J.block<2, 3>(state.world_up_index(), 3) = -normal.inverse() * jacobian.transpose() *
                                              lie::skew(state.world_up.direction());
  }
  for (int slot = 0; slot < state.num_poses(); ++slot) {
    const int index = state.pose_index(slot);
    P.middleRows(index, 6) = (adjoint * P.middleRows(index, 6)).eval();
    P.middleCols(index, 6) = (P.middleCols(index, 6) * adjoint.transpose()).eval();
    J.middleRows(index, 6).setIdentity();
  }
  for (int slot = 0; slot < state.num_landmarks(); ++slot) {
    const ObjectLandmark& landmark = state.landmarks[slot];
    if (landmark.detection_offset && !landmark.displacement) continue;
    const int index = state.landmark_index(slot);
    P.middleRows(index, 3) = (R * P.middleRows(index, 3)).eval();
    P.middleCols(index, 3) = (P.middleCols(index, 3) * R.transpose()).eval();
    if (landmark.detection_offset) {
      // d' = exp(phi^) R d: the transform's rotation error turns it, not its translation.
      J.block<3, 3>(index, 3) = -lie::skew(landmark.p_world);
      continue;
    }
    // The transform's rotation error turns the object about the new frame's origin. Its
    // component is taken at the object's first estimate, the point its pose Jacobians are
    // taken at (`ObjectLandmark::p_linearization`): the error the move adds to the state is
    // then a turn of the whole state that those Jacobians cannot see, as the true measurements
    // cannot. At the current estimate instead, every later observation of an object that has
    // moved from its first estimate would claim to tell the robot the team frame's rotation
    // (by J [p_linearization - p_world]x on it): information that is not there. What the two
    // points' difference leaves out is counted by object_first_estimate_noise
    // (docs/estimator.md, "The first estimate's mismatch").
    J.block<3, 3>(index, 0).setIdentity();
    J.block<3, 3>(index, 3) = -lie::skew(state.landmarks[slot].p_linearization);
  }
  if (correlated_slot < 0) {
    P += J * covariance * J.transpose();
  } else {
    // P <- (G - K) P (G - K)^T + J e_ind J^T with K = J Ad S_slot. With P_G = G P G^T (above)
    // and G's block of that pose being Ad, G P K^T = P_G[:, slot] J^T and K P K^T =
    // J P_G[slot, slot] J^T.
    const int pose = state.pose_index(correlated_slot);
    const Eigen::MatrixXd X = P.middleCols(pose, 6);
    const lie::Matrix6d at_pose = X.middleRows(pose, 6);
    P.noalias() -= X * J.transpose();
    P.noalias() -= J * X.transpose();
    P.noalias() += J * (at_pose + independent) * J.transpose();
  }
  symmetrize(state);
  // 3. Archived objects, each with its own share of the transform's error.
  for (auto& [id, estimate] : state.archived) {
    estimate.p_world = T_new_old * estimate.p_world;
    Eigen::Matrix<double, 3, 6> J_object;
    J_object.leftCols<3>().setIdentity();
    J_object.rightCols<3>() = -lie::skew(estimate.p_world);
    estimate.covariance =
        R * estimate.covariance * R.transpose() + J_object * covariance * J_object.transpose();
    estimate.covariance = 0.5 * (estimate.covariance + estimate.covariance.transpose()).eval();
  }
  // What was known of them relative to the robot only turns with the frame.
  for (auto& [id, local] : state.archived_local_covariance) local = R * local * R.transpose();
}

void StateHelper::symmetrize(State& state) {
  state.covariance = 0.5 * (state.covariance + state.covariance.transpose()).eval();
}

NewestPoseConditioning::NewestPoseConditioning(const State& state)
    : state_(state),
      pose_(state.pose_index(state.num_poses() - 1)),
      pose_llt_(state.covariance.block<6, 6>(pose_, pose_)) {}

std::optional<Eigen::Matrix3d> NewestPoseConditioning::of(int index,
                                                          const Eigen::Matrix3d& marginal) const {
  if (pose_llt_.info() != Eigen::Success) return std::nullopt;
  const Eigen::Matrix<double, 3, 6> cross = state_.covariance.block<3, 6>(index, pose_);
  const Eigen::Matrix3d conditioned = marginal - cross * pose_llt_.solve(cross.transpose());
  if (Eigen::LLT<Eigen::Matrix3d>(conditioned).info() != Eigen::Success) return std::nullopt;
  return 0.5 * (conditioned + conditioned.transpose());
}

}  // namespace concord
