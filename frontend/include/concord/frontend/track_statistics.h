#pragma once
/// \file
/// The front-end's own estimate of its point-feature noise, without ground truth: every track
/// with enough observations is triangulated (Gauss-Newton on its stereo reprojections) in the
/// camera poses that the odometry integrates to, and the residuals' robust spread is the noise
/// per image coordinate. It includes what the estimator will see of a track (tracking drift along
/// it, stereo matching error, the odometry's short-term error), not only the stereo row noise.
/// OpenCV-free.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <vector>

#include "concord/estimator/types.h"

namespace concord::frontend {

struct TrackConsistency {
  /// Robust standard deviation of one image coordinate (1.4826 median absolute residual,
  /// corrected for the three parameters fitted per track), pixels; 0 without tracks.
  double sigma = 0.0;
  int tracks = 0;
  long long residuals = 0;
};

/// `odometry[k-1]` is T_body(k-1)_body(k); `features` the tracks per frame (rectified pixels of
/// `camera`). Tracks with fewer than min_observations observations are not used.
[[nodiscard]] TrackConsistency track_consistency(
    const StereoCamera& camera, const std::vector<Eigen::Isometry3d>& odometry,
    const std::vector<std::vector<StereoObservation>>& features, int min_observations = 4);

/// A noise level per observation from the tracker's alignment variances
/// (TrackedFrame::alignment_variances): sigma_left^2 = scale_left * v_left for each coordinate of
/// the left image's position, sigma_right^2 = sigma_left^2 + scale_stereo * v_stereo for the right
/// image's (its match is the left one's plus the stereo alignment's). The scales keep the run's
/// mean level at the front-end's own (track_consistency's sigma, no ground truth): the left
/// image's mean variance is sigma^2, and so is the stereo part's (docs/frontend.md, "A noise
/// level per observation").
struct ObservationNoise {
  double scale_left = 0.0;
  double scale_stereo = 0.0;
  /// The variance an observation takes where none was measured: each kind's median over the run.
  double typical_left = 0.0;
  double typical_stereo = 0.0;
  long long observations = 0;
  /// A measured variance is at least this fraction of the typical one.
  static constexpr double kFloor = 0.01;

  /// Fitted (false: no variance of one kind was measured, or no noise level to scale to).
  bool valid() const { return scale_left > 0.0; }
  /// (sigma_left, sigma_right) of an observation with these variances (NaN: not measured), px.
  Eigen::Vector2d sigma(float left_variance, float stereo_variance) const;
};

/// The ObservationNoise of a run whose mean noise per coordinate is `sigma` (px): `variances[k][n]`
/// belongs to `features[k][n]`.
[[nodiscard]] ObservationNoise fit_observation_noise(
    const std::vector<std::vector<StereoObservation>>& features,
    const std::vector<std::vector<std::array<float, 2>>>& variances, double sigma);

/// The ObservationNoise of a live source (the daemon's image source), frame by frame: each
/// kind's scale from the mean of the variances measured so far (which an unmeasured one also
/// takes), the mean level `sigma` (px, per coordinate) given, e.g. the estimator's feature_noise.
/// The same model as fit_observation_noise, with running means for the run's.
class RunningObservationNoise {
 public:
  explicit RunningObservationNoise(double sigma) : sigma_(sigma) {}

  /// Adds this frame's variances (same order as `features`) to the running means and sets each
  /// observation's sigma; leaves them zero (the configured noise) until both kinds were measured.
  void apply(std::vector<StereoObservation>& features,
             const std::vector<std::array<float, 2>>& variances);

 private:
  double sigma_;
  std::array<double, 2> sums_{0.0, 0.0};
  std::array<long long, 2> counts_{0, 0};
};

}  // namespace concord::frontend
