#pragma once
/// Shared helpers for the estimator tests: random SPD matrices, small states, finite differences.

#include <Eigen/Core>
#include <random>
#include <vector>

#include "concord/estimator/state.h"
#include "concord/estimator/types.h"

namespace concord::testing {

/// A random symmetric positive definite matrix with eigenvalues in [low, high].
inline Eigen::MatrixXd random_spd(int n, std::mt19937& random, double low = 0.1,
                                  double high = 2.0) {
  std::normal_distribution<double> normal;
  Eigen::MatrixXd a(n, n);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) a(i, j) = normal(random);
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(a);
  const Eigen::MatrixXd q = qr.householderQ();
  std::uniform_real_distribution<double> uniform(low, high);
  Eigen::VectorXd eigenvalues(n);
  for (int i = 0; i < n; ++i) eigenvalues(i) = uniform(random);
  return q * eigenvalues.asDiagonal() * q.transpose();
}

inline Eigen::VectorXd random_vector(int n, std::mt19937& random, double scale = 1.0) {
  std::normal_distribution<double> normal(0.0, scale);
  Eigen::VectorXd v(n);
  for (int i = 0; i < n; ++i) v(i) = normal(random);
  return v;
}

/// A KITTI-like rectified stereo rig: body x forward, y left, z up; camera z forward.
/// The input of frame `frame` of a robot that moves by `step` every frame: the odometry from the
/// second frame on, and `pose` (the true T_world_body, the identity at frame 0) moved by it.
inline FrameInput straight_drive_frame(int frame, const Eigen::Isometry3d& step,
                                       Eigen::Isometry3d& pose) {
  FrameInput input;
  input.frame = frame;
  if (frame > 0) {
    input.T_previous_current = step;
    pose = pose * step;
  }
  return input;
}

inline StereoCamera kitti_like_camera() {
  StereoCamera camera;
  camera.K << 718.856, 0.0, 607.1928, 0.0, 718.856, 185.2157, 0.0, 0.0, 1.0;
  Eigen::Matrix3d R_cam_body;
  R_cam_body << 0, -1, 0, 0, 0, -1, 1, 0, 0;
  camera.T_cam0_body.linear() = R_cam_body;
  camera.T_cam0_cam1.translation() = Eigen::Vector3d(0.5323, 0.0, 0.0);
  return camera;
}

/// A state with the given poses and landmarks and a random SPD covariance.
inline State random_state(int poses, int landmarks, std::mt19937& random) {
  State state;
  std::normal_distribution<double> normal;
  for (int i = 0; i < poses; ++i) {
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.translation() = Eigen::Vector3d(i * 1.0, 0.1 * normal(random), 0.0);
    state.poses.push_back({i, pose});
  }
  for (int j = 0; j < landmarks; ++j) {
    const Eigen::Vector3d p_world(10.0 + j, normal(random), 1.0);
    state.landmarks.push_back({100 + j, p_world, 0, p_world});
  }
  state.rebuild_landmark_index();
  state.covariance = random_spd(state.dimension(), random, 0.05, 1.0);
  return state;
}

/// Whether two lists of matrices have the same shapes and the same values, bit for bit.
inline bool same_blocks(const std::vector<Eigen::MatrixXd>& a,
                        const std::vector<Eigen::MatrixXd>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (a[i].rows() != b[i].rows() || a[i].cols() != b[i].cols() || a[i] != b[i]) return false;
  }
  return true;
}

}  // namespace concord::testing
