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

}  // namespace concord::frontend
