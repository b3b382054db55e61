#pragma once
/// \file
/// Team evaluation as in the paper's §VI-A: trajectory RMSE without alignment (Table I), mean
/// object error against ground truth (Table II) and mean object position difference across robots
/// (Table III), per robot plus the team average and maximum. Pure functions, no file I/O.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "concord/estimator/types.h"

namespace concord::evaluation {

/// Normalized estimation error squared (NEES) of a set of samples of one kind, e = estimate
/// error, NEES = e^T P^-1 e with the estimator's own covariance P. For a consistent estimator the
/// NEES follows a chi-square distribution with `dof` degrees of freedom: its mean is about `dof`
/// and 95 % of the samples lie at or below the 95 % quantile of chi2(dof). Larger values mean the
/// estimator is overconfident (its covariance is smaller than its actual error), smaller values
/// that it is too cautious. NaN fields: no samples.
struct NeesSummary {
  int dof = 0;
  /// Samples that entered the summary (estimates with ground truth and a positive definite
  /// covariance).
  int samples = 0;
  double mean = std::numeric_limits<double>::quiet_NaN();
  double median = std::numeric_limits<double>::quiet_NaN();
  /// Fraction of the samples at or below chi2_{0.95}(dof).
  double inside_95 = std::numeric_limits<double>::quiet_NaN();
  /// Median of the first and of the last quarter of the samples in time order (frames; for
  /// objects, their id order): a filter that grows overconfident over a run has a last-quarter
  /// median well above its first-quarter median.
  double first_quarter_median = std::numeric_limits<double>::quiet_NaN();
  double last_quarter_median = std::numeric_limits<double>::quiet_NaN();
};

/// Summary of NEES samples (NaN samples are skipped) against chi2(dof).
NeesSummary summarize_nees(const std::vector<double>& samples, int dof);

/// NEES of one pose estimate T_hat with the 6x6 covariance of its right perturbation
/// xi = [rho; phi] (T = T_hat exp(xi^), the convention of pose_covariance.csv and /pose), against
/// the true pose: xi = log(T_hat^-1 T_true). Pose is 6-D; position (rho with the translation
/// block) and orientation (phi with the rotation block) 3-D each. NaN where the covariance (block)
/// is not positive definite.
struct PoseNees {
  double pose = std::numeric_limits<double>::quiet_NaN();
  double position = std::numeric_limits<double>::quiet_NaN();
  double orientation = std::numeric_limits<double>::quiet_NaN();
};
PoseNees pose_nees(const Eigen::Isometry3d& estimate, const Eigen::Matrix<double, 6, 6>& covariance,
                   const Eigen::Isometry3d& truth);

/// NEES of a point estimate with covariance against the true point (3-D); NaN when the covariance
/// is not positive definite.
double point_nees(const Eigen::Vector3d& estimate, const Eigen::Matrix3d& covariance,
                  const Eigen::Vector3d& truth);

/// Metrics of one robot. A double field is NaN when there is nothing to evaluate (for example no
/// estimated object has ground truth).
struct RobotMetrics {
  /// Robot index (position in the team), -1 for the team average and maximum.
  int robot = 0;
  /// sqrt(mean ||t_est(k) - t_gt(k)||^2) over all frames, no alignment (Table I).
  double trajectory_rmse = std::numeric_limits<double>::quiet_NaN();
  /// The same for dead reckoning: T_gt(0) composed with the odometry (the baseline row).
  double odometry_rmse = std::numeric_limits<double>::quiet_NaN();
  /// Mean ||p_est - p_gt|| over the robot's estimated objects that have ground truth (Table II).
  double object_error = std::numeric_limits<double>::quiet_NaN();
  /// Number of estimated objects that have ground truth (the terms of object_error).
  int objects_evaluated = 0;
  /// Mean ||p_i - p_j|| over every (object, other robot j) pair where robot j also estimated the
  /// object (Table III).
  double disagreement = std::numeric_limits<double>::quiet_NaN();
  /// Number of (object, other robot) pairs (the terms of disagreement).
  int disagreement_pairs = 0;
  /// Number of evaluated trajectory frames.
  int frames = 0;
  /// Consistency: NEES of every frame's online pose estimate (6-D, and its position and
  /// orientation parts, 3-D each; needs the pose covariances), and of the final object
  /// estimates that have ground truth (3-D).
  NeesSummary pose_nees{6};
  NeesSummary position_nees{3};
  NeesSummary orientation_nees{3};
  NeesSummary object_nees{3};
};

/// Metrics of the whole team.
struct TeamMetrics {
  /// One entry per robot, in robot order.
  std::vector<RobotMetrics> robots;
  /// Mean over robots of each field. NaN-aware: robots with NaN in a field are skipped for that
  /// field (NaN if every robot has NaN). Integer fields are rounded to the nearest integer.
  /// robot = -1.
  RobotMetrics average;
  /// Maximum over robots of each field, with the same NaN rule. robot = -1.
  RobotMetrics maximum;
};

/// What one robot estimated.
struct RobotResult {
  /// Estimated T_world_body per frame.
  std::vector<Eigen::Isometry3d> trajectory;
  /// Estimated object positions with their covariances; each id at most once.
  std::vector<ObjectEstimate> objects;
  /// Covariance of the right perturbation of each estimated pose (one per trajectory pose), as in
  /// pose_covariance.csv; empty when the run did not record them (no pose NEES then).
  std::vector<Eigen::Matrix<double, 6, 6>> pose_covariances;
};

/// Ground truth and measured motion of one robot.
struct RobotTruth {
  /// True T_world_body per frame.
  std::vector<Eigen::Isometry3d> groundtruth;
  /// Measured T_body(k-1)_body(k), groundtruth.size() - 1 entries (empty when not available).
  std::vector<Eigen::Isometry3d> odometry;
};

/// Evaluates a team run; results[i] and truths[i] are robot i.
///
/// Throws std::invalid_argument when the two vectors differ in size, when a robot's trajectory
/// length differs from its ground-truth length (the message names the robot and both lengths),
/// when a robot's odometry is neither empty nor one shorter than its ground truth, when a robot's
/// pose covariances are neither empty nor one per trajectory pose, or when a robot lists an object
/// id twice. Empty odometry leaves odometry_rmse NaN.
TeamMetrics evaluate(const std::vector<RobotTruth>& truths, const std::vector<RobotResult>& results,
                     const std::map<LandmarkId, Eigen::Vector3d>& objects_groundtruth);

/// Pose NEES of every frame of one robot (NaN where there is no covariance or it is not positive
/// definite); empty when the result has no pose covariances. Sizes as checked by evaluate().
std::vector<double> pose_nees_series(const RobotTruth& truth, const RobotResult& result);

/// Root mean square of the translation differences, sqrt(mean ||t_est(k) - t_gt(k)||^2), without
/// alignment. NaN for empty input. Both vectors must have the same length (asserted).
double translation_rmse(const std::vector<Eigen::Isometry3d>& estimate,
                        const std::vector<Eigen::Isometry3d>& groundtruth);

/// Odometry-only trajectory: start, then T(k) = T(k-1) * odometry[k-1]; odometry.size() + 1 poses.
std::vector<Eigen::Isometry3d> dead_reckoning(const Eigen::Isometry3d& start,
                                              const std::vector<Eigen::Isometry3d>& odometry);

/// {"robots": [...], "average": {...}, "maximum": {...}}, each entry with the RobotMetrics field
/// names as keys; NaN is written as null.
nlohmann::json to_json(const TeamMetrics& metrics);

/// A plain-text table like the paper's Tables I-III: the title, a header, one row per robot plus
/// Avg and Max, columns "traj RMSE m", "odom RMSE m", "object err m", "disagreement m", "objects";
/// fixed 3 decimals, "-" for NaN. When any NEES was evaluated, a second table follows with the
/// mean, median and fraction inside the 95 % bound of the pose, position, orientation and object
/// NEES.
std::string format_table(const TeamMetrics& metrics, const std::string& title);

}  // namespace concord::evaluation
