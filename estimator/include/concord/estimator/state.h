#pragma once
/// \file
/// The filter state of one robot (eq. 18): a sliding window of body poses and the positions of
/// object landmarks, with one joint covariance over the error state
///   [eps_0 .. eps_{c-1}, (d~), p~_0 .. p~_{m-1}],  T_world_body = exp(eps^) * T_hat,
///   p = p_hat + p~,  d = d_hat + d~,
/// where d, present when the options ask for it (disparity_offset_sigma > 0), is a constant
/// offset of the right image's horizontal coordinate: the stereo calibration's error, estimated
/// online (an error shared by every observation, which no per-observation noise can model).
///
/// Pose errors are left (world-frame) perturbations, not the right perturbations of eq. (20):
/// both describe the same Gaussian to first order (eps_left = Ad(T_hat) eps_right), but with the
/// left one a change of the whole team's world frame moves every pose error by the same constant
/// vector, whatever the estimates. The directions the robot cannot observe (its own world frame)
/// then stay fixed as the estimates change, and the filter does not gain information along them
/// from linearization errors (the inconsistency of the standard EKF/MSCKF; the invariant-EKF
/// argument of Barrau and Bonnabel). Outputs (current_pose_covariance, pose_covariance.csv,
/// /pose) are converted to the right perturbation. See docs/estimator.md.
/// The same property moves a state into another frame (StateHelper::reanchor, when a robot that
/// started at an unknown pose joins its team's frame): p_new = T p gives eps' = Ad(T) eps + e for
/// every pose, where e is the left perturbation of the uncertain T.
/// Objects that left the joint state (archived) are kept as independent marginals.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <deque>
#include <map>
#include <vector>

#include "concord/estimator/types.h"

namespace concord {

/// One body pose in the window.
struct PoseClone {
  int frame = 0;
  Eigen::Isometry3d T_world_body = Eigen::Isometry3d::Identity();
};

/// One object landmark in the joint state.
struct ObjectLandmark {
  LandmarkId id = 0;
  Eigen::Vector3d p_world = Eigen::Vector3d::Zero();
  int last_observed_frame = 0;
  /// Where the landmark entered the state (its first estimate): the pose Jacobians of its
  /// observations are evaluated here, so that every observation of it agrees on the unobservable
  /// directions (first-estimate Jacobians; the residual uses p_world).
  Eigen::Vector3d p_linearization = Eigen::Vector3d::Zero();
  /// Archived (object_archive_mode consider): not observed for object_archive_after_frames. It
  /// stays in the joint covariance as a Schmidt "consider" state: the robot's own updates keep
  /// its cross-covariances with the rest of the state current but leave its mean and covariance
  /// as they are (StateHelper::update); consensus averages it with the other in-state objects (in
  /// the joint block of the robot's marginal). Observed again, it is active again, with every
  /// correlation it had.
  bool archived = false;
};

class State {
 public:
  static constexpr int kPoseDim = 6;
  static constexpr int kLandmarkDim = 3;

  /// Poses in the window, oldest first.
  std::deque<PoseClone> poses;
  /// Object landmarks in the joint state, in covariance order.
  std::vector<ObjectLandmark> landmarks;
  /// Objects outside the joint state: independent Gaussian marginals, by id.
  std::map<LandmarkId, ObjectEstimate> archived;
  /// Last frame each archived object was observed (for bookkeeping and output).
  std::map<LandmarkId, int> archived_last_observed;

  /// Calibration entries between the poses and the landmarks: 1 with a disparity offset, else 0.
  int calibration_dim = 0;
  /// Estimated offset of the right image's horizontal coordinate (image units): an observation
  /// is u_right = u_right(true) + disparity_offset. Meaningful when calibration_dim is 1.
  double disparity_offset = 0.0;

  /// Joint covariance, (6 * poses + calibration_dim + 3 * landmarks) square.
  Eigen::MatrixXd covariance;

  int dimension() const {
    return pose_block_size() + calibration_dim + kLandmarkDim * num_landmarks();
  }
  int num_poses() const { return static_cast<int>(poses.size()); }
  int num_landmarks() const { return static_cast<int>(landmarks.size()); }
  int pose_block_size() const { return kPoseDim * num_poses(); }
  /// Covariance index of pose slot i (0 = oldest).
  int pose_index(int slot) const { return kPoseDim * slot; }
  /// Covariance index of the disparity offset (when calibration_dim is 1).
  int calibration_index() const { return pose_block_size(); }
  /// Covariance index of landmark slot i.
  int landmark_index(int slot) const {
    return pose_block_size() + calibration_dim + kLandmarkDim * slot;
  }

  /// Slot of the pose of a frame in the window, or -1.
  int pose_slot(int frame) const;
  /// Slot of an in-state landmark, or -1.
  int landmark_slot(LandmarkId id) const;

  const PoseClone& newest_pose() const { return poses.back(); }

  /// Every object the robot holds, joint and archived, sorted by id.
  std::vector<LandmarkId> object_ids() const;
  /// Estimates of every object the robot holds, sorted by id.
  std::vector<ObjectEstimate> objects() const;

  /// Keeps the slot index current; called by whoever edits landmarks.
  void rebuild_landmark_index();

 private:
  std::map<LandmarkId, int> landmark_slots_;
};

}  // namespace concord
