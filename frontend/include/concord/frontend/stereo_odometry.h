#pragma once
/// \file
/// Frame-to-frame motion for the estimator's prediction step (eq. 22-23): stereo visual odometry
/// from the front-end's tracks, or the robot's own odometry (wheels, VIO) read from a file, both
/// behind one interface, OdometrySource. OpenCV-free.
///
/// StereoVisualOdometry (docs/frontend.md, "Visual odometry"):
///   1. Tracks seen at k-1 and k with a disparity at k-1 are triangulated in camera k-1.
///   2. PnP + RANSAC (OpenCV, P3P minimal sets) on those points and their left positions at k.
///   3. Gauss-Newton refinement of T_cam(k-1)_cam(k) on the stereo reprojection (u_left, v_left,
///      u_right) at k of every point, each residual weighted by the inverse of its covariance:
///      the pixel noise at k plus the triangulation uncertainty of the point at k-1 carried
///      through the projection (first order). Points outside a chi-square gate are outliers.
///   4. Covariance of the right perturbation xi = [rho; phi] of T_cam(k-1)_cam(k): the inverse of
///      the Gauss-Newton normal matrix, scaled up by the residuals' chi-square per degree of
///      freedom when that exceeds 1, then carried into the body frame with the adjoint of
///      T_body_cam.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <filesystem>
#include <span>
#include <vector>

#include "concord/estimator/types.h"
#include "concord/frontend/frontend_options.h"

namespace concord::frontend {

using Matrix6d = Eigen::Matrix<double, 6, 6>;

/// The motion from frame k-1 to frame k.
struct MotionEstimate {
  /// False when no motion could be measured: T_previous_current is then the previous motion and
  /// the covariance OdometryOptions' failure sigmas.
  bool valid = false;
  /// T_body(k-1)_body(k).
  Eigen::Isometry3d T_previous_current = Eigen::Isometry3d::Identity();
  /// Covariance of the right perturbation [rho; phi] of T_previous_current (metres, radians),
  /// the estimator's convention (eq. 23).
  Matrix6d covariance = Matrix6d::Identity();
  /// Tracks seen in both frames and triangulated at k-1, RANSAC inliers, final inliers.
  int candidates = 0;
  int ransac_inliers = 0;
  int inliers = 0;
  /// Tracks judged wrong (for the tracker to drop).
  std::vector<LandmarkId> outliers;
  /// Weighted squared residual per degree of freedom of the final inliers (1 when the noise
  /// model fits).
  double chi2_per_dof = 0.0;
};

/// A source of frame-to-frame motion.
class OdometrySource {
 public:
  virtual ~OdometrySource() = default;
  /// The motion from frame `frame` - 1 to `frame` (>= 1), given both frames' tracks (rectified
  /// pixels, sorted by id as the tracker gives them).
  [[nodiscard]] virtual MotionEstimate estimate(int frame,
                                                std::span<const StereoObservation> previous,
                                                std::span<const StereoObservation> current) = 0;
};

/// Stereo visual odometry on a rectified camera (K, T_cam0_body, baseline along x).
class StereoVisualOdometry final : public OdometrySource {
 public:
  /// Throws FrontendError if the options are invalid.
  StereoVisualOdometry(const StereoCamera& camera, const OdometryOptions& options);

  MotionEstimate estimate(int frame, std::span<const StereoObservation> previous,
                          std::span<const StereoObservation> current) override;

 private:
  StereoCamera camera_;
  OdometryOptions options_;
  Eigen::Isometry3d last_motion_ = Eigen::Isometry3d::Identity();
};

/// The robot's own odometry: entry k-1 of a list of T_body(k-1)_body(k) (a KITTI pose file, as
/// a dataset's odometry.kitti) with a fixed covariance.
class FileOdometry final : public OdometrySource {
 public:
  FileOdometry(std::vector<Eigen::Isometry3d> motions, const Matrix6d& covariance);

  /// Reads a KITTI pose file of motions; the covariance is diagonal with the given standard
  /// deviations per axis. Throws FrontendError (naming the file and line) on bad input.
  [[nodiscard]] static FileOdometry read(const std::filesystem::path& file,
                                         double translation_sigma, double rotation_sigma);

  /// Number of motions (frames - 1 of the sequence it belongs to).
  int size() const { return static_cast<int>(motions_.size()); }

  /// Throws FrontendError if `frame` has no motion in the file.
  MotionEstimate estimate(int frame, std::span<const StereoObservation> previous,
                          std::span<const StereoObservation> current) override;

 private:
  std::vector<Eigen::Isometry3d> motions_;
  Matrix6d covariance_;
};

/// Rectified stereo triangulation: the point in the left camera frame of (u_left, v_left,
/// u_right, v_right), or nothing unless the disparity is at least min_disparity.
[[nodiscard]] std::optional<Eigen::Vector3d> triangulate(const StereoCamera& camera,
                                                         const Eigen::Vector4d& uv,
                                                         double min_disparity);

}  // namespace concord::frontend
