#pragma once
/// \file
/// The MSCKF update with point-feature tracks (opportunistic features, §V-D, eq. 24-28): tracks
/// that ended or fill the window are triangulated, linearized, projected onto the left null
/// space of their point Jacobian, chi-square gated, stacked, compressed and applied at once.

#include <map>
#include <vector>

#include "concord/estimator/options.h"
#include "concord/estimator/state.h"
#include "concord/estimator/updater_helper.h"

namespace concord {

struct FeatureUpdateStats {
  int observations = 0;
  int tracks_used = 0;      ///< tracks that entered the update
  int tracks_rejected = 0;  ///< triangulation, distance or chi-square failures
  int rows = 0;             ///< residual rows after null-space projection, before compression
  int update_failures = 0;  ///< Kalman updates refused (innovation not positive definite)
};

class FeatureUpdater {
 public:
  FeatureUpdater(const EstimatorOptions& options, const StereoCamera& camera);

  /// Adds the observations of the state's newest frame and runs the update with the tracks that
  /// ended (not seen this frame) or have as many observations as the window has poses.
  FeatureUpdateStats process(State& state, const std::vector<StereoObservation>& features);

  /// Tracks currently held (for tests and metrics).
  std::size_t num_tracks() const { return tracks_.size(); }

 private:
  /// Whitens a track's rows (normalized units): each observation's own noise (its sigma, or the
  /// configured noise) and, with feature_drift_sigma, the track's random slope.
  void whiten(LinearizedTrack& track, const std::vector<TrackObservation>& observations);
  /// The matrix that whitens one observation's four rows (normalized units).
  Eigen::Matrix4d observation_whitening(const TrackObservation& observation) const;

  EstimatorOptions options_;
  StereoCamera camera_;
  /// Whitens an observation's four rows (normalized units) under the configured feature_noise.
  Eigen::Matrix4d whitening_;
  /// S^T of eq. (25) for one observation, 4 x 6, in normalized units (whitened where used).
  Eigen::Matrix<double, 4, 6> correlation_transposed_;
  bool has_correlation_;
  /// A track's slope in its whitened rows (4n x 2, the drift model's U), U times the inverse
  /// root's middle factor, and U^T times the rows: kept between tracks so that a frame's updates
  /// do not allocate them anew.
  Eigen::MatrixXd drift_rows_;
  Eigen::MatrixXd drift_rows_middle_;
  Eigen::Matrix<double, 2, Eigen::Dynamic> drift_projected_;
  std::map<LandmarkId, std::vector<TrackObservation>> tracks_;
};

}  // namespace concord
