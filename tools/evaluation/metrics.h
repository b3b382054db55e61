#pragma once
/// \file
/// Team evaluation as in the paper's §VI-A: trajectory RMSE without alignment (Table I), mean
/// object error against ground truth (Table II) and mean object position difference across robots
/// (Table III), per robot plus the team average and maximum. Pure functions, no file I/O.
///
/// Negotiated runs (issue 11): a robot's estimates are in the frame it was in at the time (its own
/// start frame, then its team's: the start frame of the team's lowest robot, or the world), so the
/// ground truth is moved into that frame before comparing (T_F_world = truth of robot F at frame
/// 0, inverted); objects are compared through the robot's truth ids; association precision and
/// recall and alignment errors are reported.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
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
  /// Trajectory RMSE over the frames from `first_frame` on (the robot's alignment frame, or one
  /// given to evaluate), all in the team frame.
  double trajectory_rmse_aligned = std::numeric_limits<double>::quiet_NaN();
  int first_frame = 0;
  /// Alignment (negotiated runs; NaN otherwise): whether the robot moved into another robot's
  /// frame, at which frame, the error of its T_team_own against the truth (metres, degrees), and
  /// the error of its pose at that frame in the team frame (metres, degrees).
  int moved = 0;
  int aligned_at_frame = 0;
  double alignment_translation_error = std::numeric_limits<double>::quiet_NaN();
  double alignment_rotation_error_degrees = std::numeric_limits<double>::quiet_NaN();
  double aligned_pose_error = std::numeric_limits<double>::quiet_NaN();
  double aligned_pose_rotation_error_degrees = std::numeric_limits<double>::quiet_NaN();
  /// NEES (6-D) of T_team_own against the truth under its covariance, the left perturbation
  /// log(T_true T_team_own^-1); NaN when the covariance is not known or not positive definite.
  double alignment_nees = std::numeric_limits<double>::quiet_NaN();
  /// Consistency: NEES of every frame's online pose estimate (6-D, and its position and
  /// orientation parts, 3-D each; needs the pose covariances), and of the final object
  /// estimates that have ground truth (3-D).
  NeesSummary pose_nees{6};
  NeesSummary position_nees{3};
  NeesSummary orientation_nees{3};
  NeesSummary object_nees{3};
};

/// Association against the truth ids: over every pair of robots, the pairs of objects that share a
/// team id (linked) and how many are the same physical object (precision), and of the physical
/// objects each pair of robots observed in at least `min_frames` frames each, how many they
/// linked (recall); also over the pairs of robots that ended in one frame.
struct AssociationMetrics {
  int linked_pairs = 0;
  int correct_pairs = 0;
  double precision = std::numeric_limits<double>::quiet_NaN();
  int common_objects = 0;
  int found = 0;
  double recall = std::numeric_limits<double>::quiet_NaN();
  int common_objects_aligned = 0;
  int found_aligned = 0;
  double recall_aligned = std::numeric_limits<double>::quiet_NaN();
  /// Robot pairs that ended in one frame, of all pairs.
  int pairs_in_one_frame = 0;
  int robot_pairs = 0;
};

/// The team's trajectory up to one rigid transform: every pose, from each robot's first frame
/// on, of the robots whose estimates end in robot 0's frame (its own, or the team frame it joined),
/// fitted to the truth in that frame by a single rotation and translation (least squares on the
/// positions, Umeyama without scale) and the RMSE of what is left, and the objects under that fit.
/// It separates an error of the
/// team's frame as a whole (e.g. robot 0's early heading drift, which the whole negotiated map then
/// shares) from the robots' errors relative to each other. NaN when fewer than three poses.
struct TeamAlignedMetrics {
  double trajectory_rmse = std::numeric_limits<double>::quiet_NaN();
  /// Object error (mean over those robots of their mean object error) with the same fit applied
  /// to their final objects.
  double object_error = std::numeric_limits<double>::quiet_NaN();
  /// The fitted transform's rotation angle (degrees) and translation length (metres).
  double rotation_degrees = std::numeric_limits<double>::quiet_NaN();
  double translation = std::numeric_limits<double>::quiet_NaN();
  /// Robots and poses that took part.
  int robots = 0;
  int poses = 0;
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
  /// Association against the truth (when the results carry team ids).
  std::optional<AssociationMetrics> association;
  TeamAlignedMetrics team_aligned;
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
  /// Frame of each trajectory pose: nullopt for the world, else the robot whose start frame;
  /// empty: all in the world frame.
  std::vector<std::optional<int>> trajectory_frames = {};
  /// Team id of each object (parallel to objects, -1 while unshared); empty: none.
  std::vector<LandmarkId> team_ids = {};
  /// Alignment (alignment.json): the first frame in the final frame, whether the robot moved,
  /// and its T_team_own.
  int aligned_at_frame = 0;
  bool moved = false;
  Eigen::Isometry3d T_team_own = Eigen::Isometry3d::Identity();
  /// Its covariance (left perturbation in the team frame, [rho; phi]); zero: not known.
  Eigen::Matrix<double, 6, 6> T_team_own_covariance = Eigen::Matrix<double, 6, 6>::Zero();
};

/// Ground truth and measured motion of one robot.
struct RobotTruth {
  /// True T_world_body per frame.
  std::vector<Eigen::Isometry3d> groundtruth;
  /// Measured T_body(k-1)_body(k), groundtruth.size() - 1 entries (empty when not available).
  std::vector<Eigen::Isometry3d> odometry;
  /// Private object id -> ground-truth id (-1: a false detection); empty: ids are global.
  std::map<LandmarkId, LandmarkId> truth_ids = {};
  /// Frames in which the robot observed each ground-truth object (by truth id), for recall.
  std::map<LandmarkId, int> frames_observed = {};
};

/// What evaluate() does beyond the defaults.
struct EvaluationOptions {
  /// Per robot, the first frame of trajectory_rmse_aligned (e.g. another run's alignment frames,
  /// to compare a run with known starts over the same frames); empty: each result's own
  /// aligned_at_frame.
  std::vector<int> first_frames;
  /// Recall counts objects observed by both robots of a pair in at least this many frames each.
  int recall_min_frames = 10;
};

/// Evaluates a team run; results[i] and truths[i] are robot i.
///
/// Throws std::invalid_argument when the two vectors differ in size, when a robot's trajectory
/// length differs from its ground-truth length (the message names the robot and both lengths),
/// when a robot's odometry is neither empty nor one shorter than its ground truth, when a robot's
/// pose covariances are neither empty nor one per trajectory pose, or when a robot lists an object
/// id twice. Empty odometry leaves odometry_rmse NaN.
TeamMetrics evaluate(const std::vector<RobotTruth>& truths, const std::vector<RobotResult>& results,
                     const std::map<LandmarkId, Eigen::Vector3d>& objects_groundtruth,
                     const EvaluationOptions& options = {});

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
