#pragma once
/// \file
/// Stateless kernels shared by the object and point-feature updaters (after OpenVINS's
/// UpdaterHelper): the stereo projection model with its Jacobians, triangulation, linearization
/// of a track against the window, null-space projection (eq. 24), measurement compression and
/// the chi-square gate.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <optional>
#include <vector>

#include "concord/estimator/options.h"
#include "concord/estimator/state.h"
#include "concord/estimator/types.h"

namespace concord {

/// Predicted stereo observation of a world point and its Jacobians.
struct StereoProjection {
  Eigen::Vector4d xy = Eigen::Vector4d::Zero();  ///< normalized (x_l, y_l, x_r, y_r)
  /// d xy / d eps, left perturbation of T_world_body (T = exp(eps^) T_hat), eps = [rho; phi]:
  /// jacobian_point * [-I, [p_world]_x] (see pose_jacobian).
  Eigen::Matrix<double, 4, 6> jacobian_pose = Eigen::Matrix<double, 4, 6>::Zero();
  /// d xy / d p_world.
  Eigen::Matrix<double, 4, 3> jacobian_point = Eigen::Matrix<double, 4, 3>::Zero();
  double depth_left = 0.0;
  double depth_right = 0.0;
};

/// A track linearized against the window: residual = H_state x~ + H_point p~ + v.
struct LinearizedTrack {
  Eigen::MatrixXd H_state;  ///< rows x state dimension
  Eigen::MatrixXd H_point;  ///< rows x 3
  Eigen::VectorXd residual;
  /// Rows of the newest frame's observation (for the correlated-noise term S), or -1.
  int newest_frame_row = -1;
};

class UpdaterHelper {
 public:
  /// Projects p_world into both cameras of a body at T_world_body. Returns nothing when the
  /// point is not in front of both cameras (depth below min_depth).
  static std::optional<StereoProjection> project(const StereoCamera& camera,
                                                 const Eigen::Isometry3d& T_world_body,
                                                 const Eigen::Vector3d& p_world,
                                                 double min_depth = 1e-3);

  /// Triangulates a point from stereo observations at known body poses: linear least squares
  /// over every ray (both cameras), then Gauss-Newton refinement. Returns nothing when the
  /// problem is degenerate or the point ends behind a camera.
  static std::optional<Eigen::Vector3d> triangulate(
      const StereoCamera& camera, const std::vector<Eigen::Isometry3d>& T_world_bodies,
      const std::vector<Eigen::Vector4d>& observations);

  /// RMS reprojection error of a point over observations, in normalized units; infinity when
  /// the point is behind a camera.
  static double rms_reprojection_error(const StereoCamera& camera,
                                       const std::vector<Eigen::Isometry3d>& T_world_bodies,
                                       const std::vector<Eigen::Vector4d>& observations,
                                       const Eigen::Vector3d& p_world);

  /// The pose Jacobian of an observation for the state's left perturbation, evaluated with the
  /// world point p_linearization in its lever-arm term: jacobian_point * [-I, [p_lin]_x].
  /// Observations of one landmark that share p_linearization leave the robot's world frame
  /// (a common left perturbation of every pose and the landmark) unobservable, as it is.
  static Eigen::Matrix<double, 4, 6> pose_jacobian(const Eigen::Matrix<double, 4, 3>& jacobian_point,
                                                   const Eigen::Vector3d& p_linearization);

  /// Linearizes the observations (frames must be in the window) of a point at p_world against
  /// the state (with a disparity offset state, its column too: d x_r / d d = 1 / fx). landmark_slot >= 0 places H_point into H_state as well (in-state object) and
  /// evaluates the pose Jacobians at the landmark's p_linearization.
  static std::optional<LinearizedTrack> linearize(const State& state, const StereoCamera& camera,
                                                  const std::vector<TrackObservation>& track,
                                                  const Eigen::Vector3d& p_world,
                                                  int landmark_slot = -1);

  /// The level prior's measurement of the newest pose (Estimator::level_update), linearized:
  /// h = [a b]^T (R level_axis - w) = 0, where w is the world's up axis (state.world_up, which
  /// must be there) and a, b are two unit vectors perpendicular to w. H is 2 x the state
  /// dimension (the newest pose's rotation and the world up's tilt), residual = 0 - h.
  static void linearize_level(const State& state, const Eigen::Vector3d& level_axis,
                              Eigen::MatrixXd& H, Eigen::VectorXd& residual);

  /// The covariance of what a first-estimate pose Jacobian leaves out of an observation's
  /// prediction: the Jacobians at p_linearization and at the estimate p_world differ by
  /// jacobian_point [p_linearization - p_world]x on the pose's rotation error (left
  /// perturbation), whose covariance is rotation_covariance. Normalized units, 4 x 4.
  static Eigen::Matrix4d first_estimate_noise(const Eigen::Matrix<double, 4, 3>& jacobian_point,
                                              const Eigen::Vector3d& p_linearization,
                                              const Eigen::Vector3d& p_world,
                                              const Eigen::Matrix3d& rotation_covariance);

  /// An observation with the state's estimated disparity offset taken out of its right x (for
  /// triangulation, which treats the calibration as exact); unchanged without that state.
  static Eigen::Vector4d without_disparity_offset(const State& state, const StereoCamera& camera,
                                                  const Eigen::Vector4d& xy);

  /// Covariance of one stereo observation (u_left, v_left, u_right, v_right) in normalized
  /// coordinates, from its noise in image units (see StereoNoise).
  static Eigen::Matrix4d observation_covariance(const StereoNoise& noise, const StereoCamera& camera);

  /// L^-1 with L L^T = covariance: left-multiplying an observation's rows by it whitens them
  /// (unit, independent noise). covariance must be positive definite (asserted).
  static Eigen::Matrix4d whitening(const Eigen::Matrix4d& covariance);

  /// Whitens a linearized track in place: every 4-row block of H_state, H_point and the residual
  /// is left-multiplied by `whitening` (and the rows of extra, if given, likewise). Afterwards
  /// the noise of the rows is the identity.
  static void whiten_inplace(LinearizedTrack& track, const Eigen::Matrix4d& whitening,
                             Eigen::MatrixXd* extra = nullptr);

  /// eq. (24): left-multiplies H_state, residual (and the rows of extra, if given) by the
  /// transpose of an orthonormal basis of the left null space of H_point (rows - 3 rows remain).
  static void nullspace_project_inplace(Eigen::MatrixXd& H_state, Eigen::MatrixXd& H_point,
                                        Eigen::VectorXd& residual,
                                        Eigen::MatrixXd* extra = nullptr);

  /// Replaces a tall system (H, r, extra rows) by an equivalent one with at most as many rows as
  /// H has non-zero columns (thin QR); isotropic noise stays isotropic.
  static void measurement_compress_inplace(Eigen::MatrixXd& H, Eigen::VectorXd& residual,
                                           Eigen::MatrixXd* extra = nullptr);

  /// Quantile of the chi-square distribution with dof degrees of freedom.
  static double chi2_quantile(double probability, int dof);
};

}  // namespace concord
