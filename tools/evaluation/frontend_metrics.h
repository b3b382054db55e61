#pragma once
/// \file
/// How good a front-end's outputs are against ground truth (bench/frontend_bench.sh,
/// docs/results-frontend.md): odometry drift and the consistency of its covariance, point-feature
/// track positions against the true projections of the surface each track started on (rendered
/// sequences: the world's geometry), object observations against the true object centres.
/// Pure functions, no file I/O.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <limits>
#include <map>
#include <vector>

#include "concord/estimator/types.h"
#include "sim/render.h"

namespace concord::evaluation {

/// Percentiles of a sample of errors; NaN when empty.
struct ErrorStatistics {
  long long count = 0;
  double median = std::numeric_limits<double>::quiet_NaN();
  double p90 = std::numeric_limits<double>::quiet_NaN();
  double mean = std::numeric_limits<double>::quiet_NaN();
  double max = std::numeric_limits<double>::quiet_NaN();
};

ErrorStatistics error_statistics(std::vector<double> values);

/// A robot's odometry against its ground truth.
struct OdometryAccuracy {
  int motions = 0;
  /// Length of the true path, metres.
  double path_length = 0.0;
  /// Dead reckoning from the true start: position error at the last frame (metres and percent of
  /// the path length), largest and RMS position error over all frames.
  double final_error = 0.0;
  double final_error_percent = 0.0;
  double max_error = 0.0;
  double rmse = 0.0;
  /// Per-motion error xi = log(T_true^-1 T_measured) = [rho; phi]: RMS of |rho| (metres) and of
  /// |phi| (radians).
  double translation_error_rms = 0.0;
  double rotation_error_rms = 0.0;
  /// Mean normalized estimation error squared xi^T Sigma^-1 xi over motions (6 when the
  /// covariances are consistent); NaN without covariances.
  double nees_mean = std::numeric_limits<double>::quiet_NaN();
};

/// `odometry[k-1]` is T_body(k-1)_body(k); `covariances` (empty, or one per motion) of its right
/// perturbation. Throws std::invalid_argument on mismatched sizes.
OdometryAccuracy odometry_accuracy(const std::vector<Eigen::Isometry3d>& groundtruth,
                                   const std::vector<Eigen::Isometry3d>& odometry,
                                   const std::vector<Eigen::Matrix<double, 6, 6>>& covariances);

/// Point-feature tracks against a rendered world. Each track's point is where the ray through its
/// first left observation meets the world; every observation is compared with that point's true
/// projections in the left and right images.
struct TrackAccuracy {
  long long tracks = 0;
  /// Tracks whose first ray meets nothing (not evaluated).
  long long unanchored = 0;
  /// Image distance between observed and true positions, pixels: in the left image after the
  /// first observation (drift along the track), in the right image at every observation (stereo
  /// matching), and both pooled.
  ErrorStatistics left;
  ErrorStatistics right;
  ErrorStatistics all;
};

/// `camera` is the front-end's (rectified pixels), `groundtruth` T_world_body per frame,
/// `features` the tracks per frame.
TrackAccuracy track_accuracy(const sim::TexturedWorld& world, const StereoCamera& camera,
                             const std::vector<Eigen::Isometry3d>& groundtruth,
                             const std::vector<std::vector<StereoObservation>>& features);

/// Object observations against the true object centres.
struct ObjectObservationAccuracy {
  /// Left-image distance of the observation from the true centre's projection, pixels.
  ErrorStatistics centre;
  /// |observed - true| disparity, pixels.
  ErrorStatistics disparity;
  /// |depth from the observation - true depth| / true depth.
  ErrorStatistics relative_depth;
};

ObjectObservationAccuracy object_observation_accuracy(
    const StereoCamera& camera, const std::vector<Eigen::Isometry3d>& groundtruth,
    const std::vector<std::vector<StereoObservation>>& objects,
    const std::map<LandmarkId, Eigen::Vector3d>& objects_groundtruth);

}  // namespace concord::evaluation
