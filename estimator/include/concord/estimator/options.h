#pragma once
/// \file
/// Every tunable of the estimator in one place, with defaults in-class. Loaded from YAML by
/// config/ (keys are the field names), validated by validate(). Noise values and thresholds on
/// observations are in image units: the units of the observations (pixels for KITTI, normalized
/// coordinates where K is the identity).

#include <array>
#include <string>
#include <vector>

namespace concord {

/// Safeguards and parameters of the consensus step (§V-B, eq. 19-21).
struct ConsensusOptions {
  /// consensus.max_mean_shift: metres one consensus step may move a landmark mean; a larger
  /// shift is scaled down to this length (the averaged covariance is kept). 0 disables the limit.
  double max_mean_shift = 0.5;
  /// consensus.max_condition_number: a neighbour's marginal whose covariance is not positive
  /// definite or whose condition number exceeds this is skipped (its weight goes to the robot
  /// itself) and counted.
  double max_condition_number = 1e12;
  /// consensus.disagreement_gate: a neighbour's landmark whose mean is further than this
  /// Mahalanobis distance (under the sum of both covariances) from the robot's own is left out
  /// of that landmark's average. 0 disables the gate.
  double disagreement_gate = 0.0;
};

struct EstimatorOptions {
  /// window_size: c, the number of body poses kept in the sliding window (eq. 18).
  int window_size = 20;

  /// initial_position_sigma / initial_rotation_sigma: standard deviation of the known start pose
  /// (metres, radians).
  double initial_position_sigma = 1e-3;
  double initial_rotation_sigma = 1e-3;

  /// odometry_translation_sigma / odometry_rotation_sigma: per-frame standard deviation of the
  /// odometry right perturbation, W of eq. (23) (metres, radians).
  double odometry_translation_sigma = 0.1;
  double odometry_rotation_sigma = 0.1;

  // --- Objects (persistent landmarks, §V-D and §V-E) ---
  /// use_objects: process object detections at all.
  bool use_objects = true;
  /// object_sigma: standard deviation of an object detection coordinate (image units).
  double object_sigma = 5.0;
  /// object_min_observations: stereo observations in the window needed to initialize.
  int object_min_observations = 3;
  /// object_min_distance / object_max_distance: accepted depth of a new object (metres).
  double object_min_distance = 5.0;
  double object_max_distance = 30.0;
  /// object_init_max_reprojection_error: largest RMS reprojection error of a refined new object
  /// (image units).
  double object_init_max_reprojection_error = 2.0;
  /// object_update_gate: largest residual component of an in-state object observation
  /// (image units); a larger one is rejected as an outlier. 0 disables.
  double object_update_gate = 4.0;
  /// object_chi2_probability: chi-square gate probability on each object observation's
  /// Mahalanobis distance (0 disables).
  double object_chi2_probability = 0.95;
  /// object_archive_after_frames: an object not observed for this many frames leaves the joint
  /// state and is kept as an independent marginal (exact marginalization); it rejoins the state
  /// if observed again. Bounds the state for a long-lived robot. 0 keeps every object forever.
  int object_archive_after_frames = 0;

  // --- Point features (opportunistic, MSCKF update, eq. 24-28) ---
  /// use_point_features: run the MSCKF update on point-feature tracks.
  bool use_point_features = true;
  /// feature_sigma: standard deviation of a point-feature coordinate (image units).
  double feature_sigma = 1.0;
  /// feature_min_observations: stereo observations of a track needed to use it.
  int feature_min_observations = 3;
  /// feature_max_reprojection_error: largest RMS reprojection error of a triangulated track.
  double feature_max_reprojection_error = 4.0;
  /// feature_min_distance / feature_max_distance: accepted depth of a triangulated track (m).
  double feature_min_distance = 0.5;
  double feature_max_distance = 60.0;
  /// feature_chi2_probability: chi-square gate on each projected track residual (95 %).
  double feature_chi2_probability = 0.95;
  /// feature_odometry_correlation: S of eq. (25), the 6x4 correlation (row-major) between the
  /// newest odometry noise and a point-feature observation noise at the newest frame, in
  /// (metres or radians) x image units. Zero by default, as the paper found best.
  std::array<double, 24> feature_odometry_correlation{};

  ConsensusOptions consensus;

  /// Every problem with the values, each naming the key and the bad value; empty when valid.
  std::vector<std::string> validate() const;
};

}  // namespace concord
