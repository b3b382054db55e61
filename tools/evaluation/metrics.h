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
  /// Estimated object positions; each id at most once.
  std::vector<ObjectEstimate> objects;
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
/// when a robot's odometry is neither empty nor one shorter than its ground truth, or when a robot
/// lists an object id twice. Empty odometry leaves odometry_rmse NaN.
TeamMetrics evaluate(const std::vector<RobotTruth>& truths, const std::vector<RobotResult>& results,
                     const std::map<LandmarkId, Eigen::Vector3d>& objects_groundtruth);

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
/// fixed 3 decimals, "-" for NaN.
std::string format_table(const TeamMetrics& metrics, const std::string& title);

}  // namespace concord::evaluation
