#pragma once
/// \file
/// The filter state of one robot (eq. 18): a sliding window of body poses and the positions of
/// object landmarks, with one joint covariance over the error state
///   [eps_0 .. eps_{c-1}, (d~), (t~), p~_0 .. p~_{m-1}],  T_world_body = exp(eps^) * T_hat,
///   p = p_hat + p~,  d = d_hat + d~,  t = t_hat + t~,
/// where the calibration entries are there when the options ask for them:
/// - d (disparity_offset_sigma > 0): a constant offset of the right image's horizontal
///   coordinate, the stereo calibration's error, estimated online (an error shared by every
///   observation, which no per-observation noise can model);
/// - t (level_sigma > 0): the world's up axis, two tilt angles about the start's level axis (see
///   WorldUp): the start frame of a ground vehicle is level only up to the slope it stood on.
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

/// The world's up axis (opposite to gravity) in the world frame, as a state of the filter:
/// up = normalize(reference + basis * tilt), with the error on tilt (two angles, radians, to
/// first order). reference (a unit vector) and basis (two unit columns perpendicular to it) are
/// fixed when the state is made and move only with the world frame (StateHelper::reanchor), so
/// that the tilt's covariance keeps its meaning as the tilt changes.
struct WorldUp {
  Eigen::Vector3d reference = Eigen::Vector3d::UnitZ();
  Eigen::Matrix<double, 3, 2> basis = Eigen::Matrix<double, 3, 2>::Identity();
  Eigen::Vector2d tilt = Eigen::Vector2d::Zero();

  /// A world up axis of `reference` (normalized) with zero tilt.
  static WorldUp around(const Eigen::Vector3d& reference);
  /// The unit up axis.
  Eigen::Vector3d direction() const;
  /// d direction / d tilt (3 x 2).
  Eigen::Matrix<double, 3, 2> jacobian() const;
};

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
  /// The observations of it that the filter has used and whose poses may still be in the window
  /// (oldest first; normalized, as measured): with a persistent detection error
  /// (object_noise_persistent) a new observation is weighed by what it adds to them
  /// (ObjectUpdater). Empty without it.
  std::vector<TrackObservation> used_observations{};
  /// Not an object but the offset of this robot's detections of object `id` (object_offset_sigma):
  /// p_world holds [du, dv, dd], normalized image units, added to every observation's predicted
  /// left x, y and subtracted from its disparity. It is this robot's own state: outputs,
  /// marginals and the world frame leave it out (State::objects, Consensus, reanchor).
  bool detection_offset = false;
  /// With detection_offset: the offset is a displacement in space (object_displacement_sigma):
  /// p_world holds d, metres in the world frame, and the detections are centred on the object's
  /// position plus d. A change of world frame turns it (reanchor).
  bool displacement = false;
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
  /// What the robot knew of each archived object relative to itself when it archived it: the
  /// object's covariance conditioned on the newest pose of that moment (P_oo - P_op P_pp^-1
  /// P_po). Unlike the marginal it leaves out the drift the robot had accumulated by then, which
  /// the objects it mapped at about the same time share: it bounds how well their relative
  /// geometry is known (association's map descriptions). Kept in the state's frame.
  std::map<LandmarkId, Eigen::Matrix3d> archived_local_covariance;

  /// The disparity offset is a state (one calibration entry, the first).
  bool has_disparity_offset = false;
  /// Estimated offset of the right image's horizontal coordinate (image units): an observation
  /// is u_right = u_right(true) + disparity_offset. Meaningful when has_disparity_offset.
  double disparity_offset = 0.0;
  /// The world's up axis is a state (two calibration entries, after the disparity offset).
  bool has_world_up = false;
  /// Estimated up axis of the world frame. Meaningful when has_world_up.
  WorldUp world_up;

  /// Joint covariance, (6 * poses + calibration_dim() + 3 * landmarks) square.
  Eigen::MatrixXd covariance;

  int dimension() const {
    return pose_block_size() + calibration_dim() + kLandmarkDim * num_landmarks();
  }
  /// Calibration entries between the poses and the landmarks (0 to 3).
  int calibration_dim() const { return (has_disparity_offset ? 1 : 0) + (has_world_up ? 2 : 0); }
  int num_poses() const { return static_cast<int>(poses.size()); }
  int num_landmarks() const { return static_cast<int>(landmarks.size()); }
  int pose_block_size() const { return kPoseDim * num_poses(); }
  /// Covariance index of pose slot i (0 = oldest).
  int pose_index(int slot) const { return kPoseDim * slot; }
  /// Covariance index of the disparity offset (when has_disparity_offset).
  int disparity_offset_index() const { return pose_block_size(); }
  /// Covariance index of the world up axis's tilt (when has_world_up).
  int world_up_index() const { return pose_block_size() + (has_disparity_offset ? 1 : 0); }
  /// Covariance index of landmark slot i.
  int landmark_index(int slot) const {
    return pose_block_size() + calibration_dim() + kLandmarkDim * slot;
  }

  /// Slot of the pose of a frame in the window, or -1.
  int pose_slot(int frame) const;
  /// Slot of an in-state object landmark, or -1.
  int landmark_slot(LandmarkId id) const;
  /// Slot of the detection offset of object `id` (ObjectLandmark::detection_offset), or -1.
  int offset_slot(LandmarkId id) const;

  const PoseClone& newest_pose() const { return poses.back(); }

  /// Every object the robot holds, joint and archived, sorted by id (detection offsets are not
  /// objects).
  std::vector<LandmarkId> object_ids() const;
  /// Estimates of every object the robot holds, sorted by id.
  std::vector<ObjectEstimate> objects() const;

  /// Keeps the slot index current; called by whoever edits landmarks.
  void rebuild_landmark_index();

 private:
  std::map<LandmarkId, int> landmark_slots_;
  std::map<LandmarkId, int> offset_slots_;
};

}  // namespace concord
