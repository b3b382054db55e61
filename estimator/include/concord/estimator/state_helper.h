#pragma once
/// \file
/// EKF operations on a State, as stateless functions (after OpenVINS's StateHelper): correction,
/// Kalman update with optional correlated noise (eq. 26-28, Appendix C), landmark augmentation
/// (eq. 30), removal (marginalization) and marginals.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <vector>

#include "concord/estimator/lie.h"
#include "concord/estimator/state.h"

namespace concord {

class StateHelper {
 public:
  /// Applies an error-state correction: T <- exp(dx_pose^) T (eq. 21, 28, with the state's left
  /// perturbation), p <- p + dx_landmark.
  static void apply_correction(State& state, const Eigen::Ref<const Eigen::VectorXd>& correction);

  /// Kalman update with residual r = H x~ + v, v ~ N(0, noise), and optional correlation
  /// S = E[w v^T] (n x m; nullptr for none):
  ///   K = (P H^T + S)(H P H^T + V + H S + S^T H^T)^-1,  P <- P - K (H P + S^T)   (eq. 26-27, 66).
  /// Only the columns where H is non-zero are touched to form P H^T. Archived objects
  /// (ObjectLandmark::archived) are Schmidt consider states: their gain rows are zero, so their
  /// means and covariance block stay as they are while their cross-covariances follow the
  /// update (the Joseph form with that gain), in O(active x n x m). Returns false (and leaves
  /// the state unchanged) when the innovation covariance is not positive definite.
  [[nodiscard]] static bool update(State& state, const Eigen::MatrixXd& H, const Eigen::VectorXd& residual,
                     const Eigen::MatrixXd& noise, const Eigen::MatrixXd* correlation = nullptr);

  /// Mahalanobis distance squared of a residual under the innovation covariance the update
  /// uses: r^T (H P H^T + V + H S + S^T H^T)^-1 r (S: correlation as in update, or nullptr).
  /// Infinity when that covariance is not positive definite.
  static double mahalanobis_squared(const State& state, const Eigen::MatrixXd& H,
                                    const Eigen::VectorXd& residual, const Eigen::MatrixXd& noise,
                                    const Eigen::MatrixXd* correlation = nullptr);

  /// Appends a landmark whose linearized model after the QR split of eq. (29) is
  ///   r1 = H_state1 x~ + R1 p~ + v1,  v1 ~ N(0, noise1),
  /// with mean p_world (already including R1^-1 r1) and cross covariances of eq. (30);
  /// p_linearization is the point the model was linearized at (its first estimate).
  static void augment_landmark(State& state, LandmarkId id, const Eigen::Vector3d& p_world,
                               const Eigen::Vector3d& p_linearization, int frame,
                               const Eigen::MatrixXd& H_state1,
                               const Eigen::Matrix3d& R1, const Eigen::Matrix3d& noise1);

  /// Marginalizes the given landmark slots out of the joint state (drops rows and columns).
  static void remove_landmarks(State& state, const std::vector<int>& slots);

  /// Removes the oldest pose of the window (marginalization: drops its rows and columns).
  static void remove_oldest_pose(State& state);

  /// Indices of the columns of H that hold a non-zero entry (the state entries a Jacobian
  /// touches); products are formed over these only.
  static std::vector<int> nonzero_columns(const Eigen::MatrixXd& H);

  /// Moves the whole state into another frame: every pose T <- T_new_old T, every landmark (joint
  /// and archived, and its first estimate) p <- T_new_old p, where T_new_old is uncertain with
  /// covariance `covariance` as a left perturbation in the new frame, T_new_old = exp(e^) T_hat.
  /// With the state's left pose errors the new errors are, to first order,
  ///   eps' = Ad(T_hat) eps + e,   p~' = R_hat p~ + [I, -[p']_x] e,
  /// so P <- G P G^T + J covariance J^T with G = diag(Ad(T_hat) per pose, R_hat per landmark) and
  /// J stacking I (poses) and [I, -[p']_x] (landmarks): every estimate shares the transform's
  /// error. Archived objects get their own 3x3 share of it. Used when a robot that started at an
  /// unknown pose joins its team's frame.
  ///
  /// With correlated_slot >= 0 the transform was found from the state's own map as it stood
  /// relative to the pose in that slot, so its error holds that pose's error:
  /// e = e_ind - Ad(T_hat) eps_slot, with e_ind independent of the state, of covariance
  /// `independent` (a robot's map drifts with its pose; docs/association.md, "A move that keeps
  /// the map's drift"). Then G becomes G - J Ad(T_hat) S_slot: that pose's error becomes e_ind,
  /// and every other estimate keeps what the state knew of it relative to that pose, plus e_ind.
  /// Archived objects keep no correlation with the poses and take `covariance`, which must be
  /// e's whole covariance (e_ind's and the pose's, turned).
  static void reanchor(State& state, const Eigen::Isometry3d& T_new_old,
                       const lie::Matrix6d& covariance, int correlated_slot = -1,
                       const lie::Matrix6d& independent = lie::Matrix6d::Zero());

  /// Enforces symmetry of the covariance after an update.
  static void symmetrize(State& state);
};

}  // namespace concord
