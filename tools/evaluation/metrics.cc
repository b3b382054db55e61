#include "evaluation/metrics.h"

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <set>
#include <sstream>
#include <stdexcept>

#include "concord/estimator/lie.h"
#include "concord/estimator/updater_helper.h"

namespace concord::evaluation {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// The ground-truth id of a robot's object id (the id itself when ids are global), or -1.
LandmarkId truth_id_of(const RobotTruth& truth, LandmarkId id) {
  if (truth.truth_ids.empty()) return id;
  const auto it = truth.truth_ids.find(id);
  return it == truth.truth_ids.end() ? -1 : it->second;
}

/// T_F_world of a frame: identity for the world, the inverse of robot F's first true pose.
Eigen::Isometry3d frame_from_world(const std::vector<RobotTruth>& truths,
                                   const std::optional<int>& frame) {
  if (!frame) return Eigen::Isometry3d::Identity();
  if (*frame < 0 || *frame >= static_cast<int>(truths.size()) ||
      truths[*frame].groundtruth.empty()) {
    throw std::invalid_argument("frame of robot " + std::to_string(*frame) +
                                " has no ground truth");
  }
  return truths[*frame].groundtruth.front().inverse();
}

/// The frame of a robot's pose k (world when none are given).
std::optional<int> frame_at(const RobotResult& result, std::size_t k) {
  return result.trajectory_frames.empty() ? std::nullopt : result.trajectory_frames[k];
}

/// The frame of a robot's final estimates.
std::optional<int> final_frame(const RobotResult& result) {
  return result.trajectory_frames.empty() ? std::nullopt : result.trajectory_frames.back();
}

/// A robot's object estimates by truth id, in the world frame when `to_world` is given (rejects ids
/// listed twice; objects without truth are left out).
std::map<LandmarkId, Eigen::Vector3d> objects_by_id(const RobotResult& result,
                                                    const RobotTruth& truth, int robot) {
  std::map<LandmarkId, Eigen::Vector3d> positions;
  std::set<LandmarkId> seen;
  for (const ObjectEstimate& object : result.objects) {
    if (!seen.insert(object.id).second) {
      throw std::invalid_argument("robot " + std::to_string(robot) + " lists object " +
                                  std::to_string(object.id) + " more than once");
    }
    const LandmarkId truth_id = truth_id_of(truth, object.id);
    if (truth_id < 0) continue;
    positions.emplace(truth_id, object.p_world);
  }
  return positions;
}

void check_inputs(const std::vector<RobotTruth>& truths, const std::vector<RobotResult>& results) {
  if (truths.size() != results.size()) {
    throw std::invalid_argument(
        "evaluation needs one result per robot: " + std::to_string(truths.size()) +
        " ground truths, " + std::to_string(results.size()) + " results");
  }
  for (std::size_t robot = 0; robot < truths.size(); ++robot) {
    const std::size_t truth_length = truths[robot].groundtruth.size();
    const std::size_t trajectory_length = results[robot].trajectory.size();
    if (trajectory_length != truth_length) {
      throw std::invalid_argument("robot " + std::to_string(robot) + ": estimated trajectory has " +
                                  std::to_string(trajectory_length) + " poses, ground truth has " +
                                  std::to_string(truth_length));
    }
    const std::size_t covariance_length = results[robot].pose_covariances.size();
    if (covariance_length != 0 && covariance_length != trajectory_length) {
      throw std::invalid_argument("robot " + std::to_string(robot) + ": " +
                                  std::to_string(covariance_length) + " pose covariances for " +
                                  std::to_string(trajectory_length) + " poses");
    }
    const std::size_t frames_length = results[robot].trajectory_frames.size();
    if (frames_length != 0 && frames_length != trajectory_length) {
      throw std::invalid_argument("robot " + std::to_string(robot) + ": " +
                                  std::to_string(frames_length) + " trajectory frames for " +
                                  std::to_string(trajectory_length) + " poses");
    }
    if (!results[robot].team_ids.empty() &&
        results[robot].team_ids.size() != results[robot].objects.size()) {
      throw std::invalid_argument(
          "robot " + std::to_string(robot) + ": " + std::to_string(results[robot].team_ids.size()) +
          " team ids for " + std::to_string(results[robot].objects.size()) + " objects");
    }
    const std::size_t odometry_length = truths[robot].odometry.size();
    if (odometry_length != 0 && odometry_length + 1 != truth_length) {
      throw std::invalid_argument("robot " + std::to_string(robot) + ": odometry has " +
                                  std::to_string(odometry_length) + " entries, ground truth has " +
                                  std::to_string(truth_length) + " poses (expected one fewer)");
    }
  }
}

/// Mean ||p_est - p_gt|| over the estimated objects that have ground truth (Table II), the truth
/// moved into the estimates' frame by T_frame_world.
void fill_object_error(const std::map<LandmarkId, Eigen::Vector3d>& estimated,
                       const std::map<LandmarkId, Eigen::Vector3d>& objects_groundtruth,
                       const Eigen::Isometry3d& T_frame_world, RobotMetrics& metrics) {
  double error_sum = 0.0;
  int count = 0;
  for (const auto& [id, p_world] : estimated) {
    const auto truth = objects_groundtruth.find(id);
    if (truth == objects_groundtruth.end()) continue;
    error_sum += (p_world - T_frame_world * truth->second).norm();
    ++count;
  }
  metrics.objects_evaluated = count;
  metrics.object_error = count > 0 ? error_sum / count : kNaN;
}

/// Object NEES of the estimated objects that have ground truth, in id order.
NeesSummary object_nees_of(const RobotResult& result, const RobotTruth& robot_truth,
                           const std::map<LandmarkId, Eigen::Vector3d>& objects_groundtruth,
                           const Eigen::Isometry3d& T_frame_world) {
  std::vector<const ObjectEstimate*> sorted;
  for (const ObjectEstimate& object : result.objects) sorted.push_back(&object);
  std::sort(sorted.begin(), sorted.end(),
            [](const ObjectEstimate* a, const ObjectEstimate* b) { return a->id < b->id; });
  std::vector<double> samples;
  for (const ObjectEstimate* object : sorted) {
    const auto truth = objects_groundtruth.find(truth_id_of(robot_truth, object->id));
    if (truth == objects_groundtruth.end()) continue;
    samples.push_back(
        point_nees(object->p_world, object->covariance, T_frame_world * truth->second));
  }
  return summarize_nees(samples, 3);
}

/// Mean over robots (average) and maximum of every field of one NEES summary, NaN-aware; the
/// sample counts are summed (average) and maximized.
void aggregate(const std::vector<RobotMetrics>& robots, NeesSummary RobotMetrics::*field,
               RobotMetrics& average, RobotMetrics& maximum) {
  NeesSummary& mean_of = average.*field;
  NeesSummary& max_of = maximum.*field;
  mean_of.samples = 0;
  max_of.samples = 0;
  for (const RobotMetrics& metrics : robots) {
    mean_of.samples += (metrics.*field).samples;
    max_of.samples = std::max(max_of.samples, (metrics.*field).samples);
  }
  for (double NeesSummary::*value :
       {&NeesSummary::mean, &NeesSummary::median, &NeesSummary::inside_95,
        &NeesSummary::first_quarter_median, &NeesSummary::last_quarter_median}) {
    double sum = 0.0;
    double largest = -std::numeric_limits<double>::infinity();
    int count = 0;
    for (const RobotMetrics& metrics : robots) {
      const double x = (metrics.*field).*value;
      if (std::isnan(x)) continue;
      sum += x;
      largest = std::max(largest, x);
      ++count;
    }
    mean_of.*value = count > 0 ? sum / count : kNaN;
    max_of.*value = count > 0 ? largest : kNaN;
  }
}

/// Mean ||p_i - p_j|| over every (object, other robot j) pair where robot j also holds the object
/// (Table III), robots whose estimates are in one frame only.
void fill_disagreement(const std::vector<std::map<LandmarkId, Eigen::Vector3d>>& estimated,
                       const std::vector<std::optional<int>>& frames, std::size_t robot,
                       RobotMetrics& metrics) {
  double distance_sum = 0.0;
  int pairs = 0;
  for (const auto& [id, p_world] : estimated[robot]) {
    for (std::size_t other = 0; other < estimated.size(); ++other) {
      if (other == robot || frames[other] != frames[robot]) continue;
      const auto other_estimate = estimated[other].find(id);
      if (other_estimate == estimated[other].end()) continue;
      distance_sum += (p_world - other_estimate->second).norm();
      ++pairs;
    }
  }
  metrics.disagreement_pairs = pairs;
  metrics.disagreement = pairs > 0 ? distance_sum / pairs : kNaN;
}

/// Mean and maximum of one double field over robots, skipping NaN.
void aggregate(const std::vector<RobotMetrics>& robots, double RobotMetrics::*field,
               RobotMetrics& average, RobotMetrics& maximum) {
  double sum = 0.0;
  double largest = -std::numeric_limits<double>::infinity();
  int count = 0;
  for (const RobotMetrics& metrics : robots) {
    const double value = metrics.*field;
    if (std::isnan(value)) continue;
    sum += value;
    largest = std::max(largest, value);
    ++count;
  }
  average.*field = count > 0 ? sum / count : kNaN;
  maximum.*field = count > 0 ? largest : kNaN;
}

/// Mean (rounded to the nearest integer) and maximum of one integer field over robots.
void aggregate(const std::vector<RobotMetrics>& robots, int RobotMetrics::*field,
               RobotMetrics& average, RobotMetrics& maximum) {
  if (robots.empty()) return;
  double sum = 0.0;
  int largest = std::numeric_limits<int>::min();
  for (const RobotMetrics& metrics : robots) {
    sum += metrics.*field;
    largest = std::max(largest, metrics.*field);
  }
  average.*field = static_cast<int>(std::lround(sum / static_cast<double>(robots.size())));
  maximum.*field = largest;
}

nlohmann::json number_or_null(double value) {
  return std::isnan(value) ? nlohmann::json(nullptr) : nlohmann::json(value);
}

nlohmann::json nees_to_json(const NeesSummary& nees) {
  return {
      {"dof", nees.dof},
      {"samples", nees.samples},
      {"mean", number_or_null(nees.mean)},
      {"median", number_or_null(nees.median)},
      {"inside_95", number_or_null(nees.inside_95)},
      {"first_quarter_median", number_or_null(nees.first_quarter_median)},
      {"last_quarter_median", number_or_null(nees.last_quarter_median)},
  };
}

nlohmann::json robot_to_json(const RobotMetrics& metrics) {
  return {
      {"pose_nees", nees_to_json(metrics.pose_nees)},
      {"position_nees", nees_to_json(metrics.position_nees)},
      {"orientation_nees", nees_to_json(metrics.orientation_nees)},
      {"object_nees", nees_to_json(metrics.object_nees)},
      {"robot", metrics.robot},
      {"trajectory_rmse", number_or_null(metrics.trajectory_rmse)},
      {"odometry_rmse", number_or_null(metrics.odometry_rmse)},
      {"object_error", number_or_null(metrics.object_error)},
      {"objects_evaluated", metrics.objects_evaluated},
      {"disagreement", number_or_null(metrics.disagreement)},
      {"disagreement_pairs", metrics.disagreement_pairs},
      {"frames", metrics.frames},
      {"trajectory_rmse_aligned", number_or_null(metrics.trajectory_rmse_aligned)},
      {"first_frame", metrics.first_frame},
      {"moved", metrics.moved},
      {"aligned_at_frame", metrics.aligned_at_frame},
      {"alignment_translation_error", number_or_null(metrics.alignment_translation_error)},
      {"alignment_rotation_error_degrees",
       number_or_null(metrics.alignment_rotation_error_degrees)},
      {"aligned_pose_error", number_or_null(metrics.aligned_pose_error)},
      {"aligned_pose_rotation_error_degrees",
       number_or_null(metrics.aligned_pose_rotation_error_degrees)},
      {"alignment_nees", number_or_null(metrics.alignment_nees)},
  };
}

/// Fixed 3 decimals, "-" for NaN.
std::string format_metres(double value) {
  if (std::isnan(value)) return "-";
  char text[32];
  std::snprintf(text, sizeof(text), "%.3f", value);
  return text;
}

/// Median of a non-empty range (copied, partially sorted).
double median_of(std::vector<double> values) {
  const std::size_t middle = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(middle),
                   values.end());
  const double upper = values[middle];
  if (values.size() % 2 == 1) return upper;
  const double lower = *std::max_element(values.begin(),
                                         values.begin() + static_cast<std::ptrdiff_t>(middle));
  return 0.5 * (lower + upper);
}

/// e^T P^-1 e, NaN when P is not positive definite.
template <int N>
double mahalanobis_squared(const Eigen::Matrix<double, N, 1>& error,
                           const Eigen::Matrix<double, N, N>& covariance) {
  const Eigen::LLT<Eigen::Matrix<double, N, N>> llt(covariance);
  if (llt.info() != Eigen::Success || !covariance.allFinite()) return kNaN;
  return error.dot(llt.solve(error));
}

}  // namespace

NeesSummary summarize_nees(const std::vector<double>& samples, int dof) {
  NeesSummary summary;
  summary.dof = dof;
  std::vector<double> valid;
  valid.reserve(samples.size());
  for (double sample : samples) {
    if (!std::isnan(sample)) valid.push_back(sample);
  }
  summary.samples = static_cast<int>(valid.size());
  if (valid.empty()) return summary;
  const double bound = UpdaterHelper::chi2_quantile(0.95, dof);
  double sum = 0.0;
  int inside = 0;
  for (double sample : valid) {
    sum += sample;
    if (sample <= bound) ++inside;
  }
  summary.mean = sum / static_cast<double>(valid.size());
  summary.inside_95 = static_cast<double>(inside) / static_cast<double>(valid.size());
  summary.median = median_of(valid);
  const std::size_t quarter = valid.size() / 4;
  if (quarter > 0) {
    summary.first_quarter_median =
        median_of({valid.begin(), valid.begin() + static_cast<std::ptrdiff_t>(quarter)});
    summary.last_quarter_median =
        median_of({valid.end() - static_cast<std::ptrdiff_t>(quarter), valid.end()});
  }
  return summary;
}

PoseNees pose_nees(const Eigen::Isometry3d& estimate, const Eigen::Matrix<double, 6, 6>& covariance,
                   const Eigen::Isometry3d& truth) {
  const lie::Vector6d xi = lie::se3_log(estimate.inverse() * truth);
  PoseNees nees;
  nees.pose = mahalanobis_squared<6>(xi, covariance);
  nees.position = mahalanobis_squared<3>(xi.head<3>(), covariance.topLeftCorner<3, 3>());
  nees.orientation = mahalanobis_squared<3>(xi.tail<3>(), covariance.bottomRightCorner<3, 3>());
  return nees;
}

double point_nees(const Eigen::Vector3d& estimate, const Eigen::Matrix3d& covariance,
                  const Eigen::Vector3d& truth) {
  return mahalanobis_squared<3>(estimate - truth, covariance);
}

std::vector<double> pose_nees_series(const RobotTruth& truth, const RobotResult& result) {
  std::vector<double> series;
  series.reserve(result.pose_covariances.size());
  for (std::size_t frame = 0; frame < result.pose_covariances.size(); ++frame) {
    series.push_back(pose_nees(result.trajectory[frame], result.pose_covariances[frame],
                               truth.groundtruth[frame])
                         .pose);
  }
  return series;
}

double translation_rmse(const std::vector<Eigen::Isometry3d>& estimate,
                        const std::vector<Eigen::Isometry3d>& groundtruth) {
  assert(estimate.size() == groundtruth.size());
  if (groundtruth.empty()) return kNaN;
  double squared_sum = 0.0;
  for (std::size_t frame = 0; frame < groundtruth.size(); ++frame) {
    squared_sum += (estimate[frame].translation() - groundtruth[frame].translation()).squaredNorm();
  }
  return std::sqrt(squared_sum / static_cast<double>(groundtruth.size()));
}

std::vector<Eigen::Isometry3d> dead_reckoning(const Eigen::Isometry3d& start,
                                              const std::vector<Eigen::Isometry3d>& odometry) {
  std::vector<Eigen::Isometry3d> trajectory;
  trajectory.reserve(odometry.size() + 1);
  trajectory.push_back(start);
  for (const Eigen::Isometry3d& T_previous_current : odometry) {
    trajectory.push_back(trajectory.back() * T_previous_current);
  }
  return trajectory;
}

namespace {

double degrees_of(const Eigen::Matrix3d& rotation) {
  return Eigen::AngleAxisd(rotation).angle() * 180.0 / std::numbers::pi;
}

/// Precision and recall of the team ids against the truth ids (AssociationMetrics).
AssociationMetrics association_of(const std::vector<RobotTruth>& truths,
                                  const std::vector<RobotResult>& results,
                                  const std::vector<std::optional<int>>& frames, int min_frames) {
  AssociationMetrics metrics;
  const std::size_t n = results.size();
  // Per robot: team id -> truth id of its object, and truth ids it linked.
  std::vector<std::map<LandmarkId, LandmarkId>> truth_of_team(n);
  for (std::size_t r = 0; r < n; ++r) {
    for (std::size_t k = 0; k < results[r].objects.size(); ++k) {
      const LandmarkId team = results[r].team_ids[k];
      if (team < 0) continue;
      truth_of_team[r][team] = truth_id_of(truths[r], results[r].objects[k].id);
    }
  }
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t j = i + 1; j < n; ++j) {
      ++metrics.robot_pairs;
      const bool one_frame = frames[i] == frames[j];
      if (one_frame) ++metrics.pairs_in_one_frame;
      std::set<LandmarkId> linked_truths;
      for (const auto& [team, truth_i] : truth_of_team[i]) {
        const auto other = truth_of_team[j].find(team);
        if (other == truth_of_team[j].end()) continue;
        ++metrics.linked_pairs;
        if (truth_i >= 0 && truth_i == other->second) {
          ++metrics.correct_pairs;
          linked_truths.insert(truth_i);
        }
      }
      for (const auto& [truth, frames_i] : truths[i].frames_observed) {
        if (truth < 0 || frames_i < min_frames) continue;
        const auto other = truths[j].frames_observed.find(truth);
        if (other == truths[j].frames_observed.end() || other->second < min_frames) continue;
        const bool found = linked_truths.contains(truth);
        ++metrics.common_objects;
        metrics.found += found;
        if (one_frame) {
          ++metrics.common_objects_aligned;
          metrics.found_aligned += found;
        }
      }
    }
  }
  const auto ratio = [](int a, int b) {
    return b > 0 ? static_cast<double>(a) / static_cast<double>(b) : kNaN;
  };
  metrics.precision = ratio(metrics.correct_pairs, metrics.linked_pairs);
  metrics.recall = ratio(metrics.found, metrics.common_objects);
  metrics.recall_aligned = ratio(metrics.found_aligned, metrics.common_objects_aligned);
  return metrics;
}

/// TeamAlignedMetrics of the positions estimated_positions[i] against truth_positions[i], and of
/// the objects of the robots in `team` (their estimates in their final frame T_team_world).
TeamAlignedMetrics team_aligned_of(
    const std::vector<Eigen::Vector3d>& estimated_positions,
    const std::vector<Eigen::Vector3d>& truth_positions, const std::vector<std::size_t>& team,
    const std::vector<std::map<LandmarkId, Eigen::Vector3d>>& estimated_objects,
    const std::map<LandmarkId, Eigen::Vector3d>& objects_groundtruth,
    const Eigen::Isometry3d& T_team_world) {
  TeamAlignedMetrics metrics;
  metrics.robots = static_cast<int>(team.size());
  metrics.poses = static_cast<int>(estimated_positions.size());
  if (estimated_positions.size() < 3) return metrics;
  Eigen::Matrix3Xd estimated(3, metrics.poses), truth(3, metrics.poses);
  for (int i = 0; i < metrics.poses; ++i) {
    estimated.col(i) = estimated_positions[static_cast<std::size_t>(i)];
    truth.col(i) = truth_positions[static_cast<std::size_t>(i)];
  }
  const Eigen::Matrix4d fit = Eigen::umeyama(estimated, truth, false);
  const Eigen::Matrix3Xd residual =
      (fit.topLeftCorner<3, 3>() * estimated).colwise() + fit.topRightCorner<3, 1>() - truth;
  metrics.trajectory_rmse = std::sqrt(residual.squaredNorm() / static_cast<double>(residual.cols()));
  metrics.rotation_degrees = degrees_of(fit.topLeftCorner<3, 3>());
  metrics.translation = fit.topRightCorner<3, 1>().norm();
  Eigen::Isometry3d T_fit = Eigen::Isometry3d::Identity();
  T_fit.matrix() = fit;
  double robots_sum = 0.0;
  int robots_with_objects = 0;
  for (const std::size_t robot : team) {
    std::map<LandmarkId, Eigen::Vector3d> fitted;
    for (const auto& [id, p] : estimated_objects[robot]) fitted.emplace(id, T_fit * p);
    RobotMetrics robot_metrics;
    fill_object_error(fitted, objects_groundtruth, T_team_world, robot_metrics);
    if (robot_metrics.objects_evaluated == 0) continue;
    robots_sum += robot_metrics.object_error;
    ++robots_with_objects;
  }
  if (robots_with_objects > 0) metrics.object_error = robots_sum / robots_with_objects;
  return metrics;
}

}  // namespace

TeamMetrics evaluate(const std::vector<RobotTruth>& truths, const std::vector<RobotResult>& results,
                     const std::map<LandmarkId, Eigen::Vector3d>& objects_groundtruth,
                     const EvaluationOptions& options) {
  check_inputs(truths, results);
  if (!options.first_frames.empty() && options.first_frames.size() != results.size()) {
    throw std::invalid_argument("evaluation: " + std::to_string(options.first_frames.size()) +
                                " first frames for " + std::to_string(results.size()) + " robots");
  }

  std::vector<std::map<LandmarkId, Eigen::Vector3d>> estimated_objects;
  std::vector<std::optional<int>> frames;
  estimated_objects.reserve(results.size());
  for (std::size_t robot = 0; robot < results.size(); ++robot) {
    estimated_objects.push_back(
        objects_by_id(results[robot], truths[robot], static_cast<int>(robot)));
    frames.push_back(final_frame(results[robot]));
  }

  TeamMetrics team;
  // Positions for the team's rigid fit: robots ending in robot 0's frame, from their first frame
  // on, where the estimate is in that frame.
  std::vector<Eigen::Vector3d> team_estimated, team_truth;
  std::vector<std::size_t> team_robots;
  for (std::size_t robot = 0; robot < truths.size(); ++robot) {
    const RobotTruth& truth = truths[robot];
    const RobotResult& result = results[robot];
    RobotMetrics metrics;
    metrics.robot = static_cast<int>(robot);
    metrics.frames = static_cast<int>(truth.groundtruth.size());
    // The ground truth of every frame in the frame of that frame's estimate.
    std::vector<Eigen::Isometry3d> truth_in_frames;
    truth_in_frames.reserve(truth.groundtruth.size());
    for (std::size_t frame = 0; frame < truth.groundtruth.size(); ++frame) {
      truth_in_frames.push_back(frame_from_world(truths, frame_at(result, frame)) *
                                truth.groundtruth[frame]);
    }
    // 1. Trajectory RMSE without alignment (Table I), and from the alignment frame on.
    metrics.trajectory_rmse = translation_rmse(result.trajectory, truth_in_frames);
    metrics.first_frame =
        options.first_frames.empty() ? result.aligned_at_frame : options.first_frames[robot];
    metrics.first_frame = std::clamp(metrics.first_frame, 0, metrics.frames);
    metrics.trajectory_rmse_aligned =
        translation_rmse({result.trajectory.begin() + metrics.first_frame, result.trajectory.end()},
                         {truth_in_frames.begin() + metrics.first_frame, truth_in_frames.end()});
    if (frames[robot] == frames.front()) {
      team_robots.push_back(robot);
      for (int k = metrics.first_frame; k < metrics.frames; ++k) {
        if (frame_at(result, static_cast<std::size_t>(k)) != frames.front()) continue;
        team_estimated.push_back(result.trajectory[static_cast<std::size_t>(k)].translation());
        team_truth.push_back(truth_in_frames[static_cast<std::size_t>(k)].translation());
      }
    }
    // 2. The dead-reckoning baseline from the known start pose.
    if (!truth.odometry.empty()) {
      metrics.odometry_rmse = translation_rmse(
          dead_reckoning(truth.groundtruth.front(), truth.odometry), truth.groundtruth);
    }
    // 3. Object error against ground truth (Table II), in the robot's final frame.
    const Eigen::Isometry3d T_final_world = frame_from_world(truths, frames[robot]);
    fill_object_error(estimated_objects[robot], objects_groundtruth, T_final_world, metrics);
    // 4. Object position differences across robots in one frame (Table III).
    fill_disagreement(estimated_objects, frames, robot, metrics);
    // 5. Consistency: NEES of the online poses and of the final objects.
    std::vector<double> pose, position, orientation;
    for (std::size_t frame = 0; frame < result.pose_covariances.size(); ++frame) {
      const PoseNees nees = pose_nees(result.trajectory[frame], result.pose_covariances[frame],
                                      truth_in_frames[frame]);
      pose.push_back(nees.pose);
      position.push_back(nees.position);
      orientation.push_back(nees.orientation);
    }
    metrics.pose_nees = summarize_nees(pose, 6);
    metrics.position_nees = summarize_nees(position, 3);
    metrics.orientation_nees = summarize_nees(orientation, 3);
    metrics.object_nees = object_nees_of(result, truth, objects_groundtruth, T_final_world);
    // 6. Alignment: T_team_own against the truth, and the pose at the alignment frame.
    metrics.moved = result.moved ? 1 : 0;
    metrics.aligned_at_frame = result.aligned_at_frame;
    if (result.moved && !truth.groundtruth.empty()) {
      const Eigen::Isometry3d T_true = T_final_world * truth.groundtruth.front();
      const Eigen::Isometry3d error = T_true.inverse() * result.T_team_own;
      metrics.alignment_translation_error =
          (T_true.translation() - result.T_team_own.translation()).norm();
      metrics.alignment_rotation_error_degrees = degrees_of(error.linear());
      const lie::Vector6d left_error = lie::se3_log(T_true * result.T_team_own.inverse());
      const Eigen::LLT<Eigen::Matrix<double, 6, 6>> llt(result.T_team_own_covariance);
      if (!result.T_team_own_covariance.isZero() && llt.info() == Eigen::Success) {
        metrics.alignment_nees = left_error.dot(llt.solve(left_error));
      }
      const auto k = static_cast<std::size_t>(
          std::clamp(result.aligned_at_frame, 0, static_cast<int>(result.trajectory.size()) - 1));
      metrics.aligned_pose_error =
          (result.trajectory[k].translation() - truth_in_frames[k].translation()).norm();
      metrics.aligned_pose_rotation_error_degrees =
          degrees_of(truth_in_frames[k].linear().transpose() * result.trajectory[k].linear());
    }
    team.robots.push_back(metrics);
  }

  if (!frames.empty()) {
    team.team_aligned =
        team_aligned_of(team_estimated, team_truth, team_robots, estimated_objects,
                        objects_groundtruth, frame_from_world(truths, frames.front()));
  }
  team.average.robot = -1;
  team.maximum.robot = -1;
  for (double RobotMetrics::*field :
       {&RobotMetrics::trajectory_rmse, &RobotMetrics::odometry_rmse, &RobotMetrics::object_error,
        &RobotMetrics::disagreement, &RobotMetrics::trajectory_rmse_aligned,
        &RobotMetrics::alignment_translation_error, &RobotMetrics::alignment_rotation_error_degrees,
        &RobotMetrics::aligned_pose_error, &RobotMetrics::aligned_pose_rotation_error_degrees,
        &RobotMetrics::alignment_nees}) {
    aggregate(team.robots, field, team.average, team.maximum);
  }
  for (NeesSummary RobotMetrics::*field : {&RobotMetrics::pose_nees, &RobotMetrics::position_nees,
                                           &RobotMetrics::orientation_nees,
                                           &RobotMetrics::object_nees}) {
    aggregate(team.robots, field, team.average, team.maximum);
  }
  for (int RobotMetrics::*field :
       {&RobotMetrics::objects_evaluated, &RobotMetrics::disagreement_pairs, &RobotMetrics::frames,
        &RobotMetrics::first_frame, &RobotMetrics::moved, &RobotMetrics::aligned_at_frame}) {
    aggregate(team.robots, field, team.average, team.maximum);
  }
  const bool has_team_ids = std::any_of(results.begin(), results.end(),
                                        [](const RobotResult& r) { return !r.team_ids.empty(); });
  if (has_team_ids && std::all_of(results.begin(), results.end(), [](const RobotResult& r) {
        return r.team_ids.size() == r.objects.size();
      })) {
    team.association = association_of(truths, results, frames, options.recall_min_frames);
  }
  return team;
}

nlohmann::json to_json(const TeamMetrics& metrics) {
  nlohmann::json robots = nlohmann::json::array();
  for (const RobotMetrics& robot : metrics.robots) robots.push_back(robot_to_json(robot));
  nlohmann::json document = {
      {"robots", robots},
      {"average", robot_to_json(metrics.average)},
      {"maximum", robot_to_json(metrics.maximum)},
  };
  const TeamAlignedMetrics& aligned = metrics.team_aligned;
  document["team_aligned"] = {
      {"trajectory_rmse", number_or_null(aligned.trajectory_rmse)},
      {"rotation_degrees", number_or_null(aligned.rotation_degrees)},
      {"translation", number_or_null(aligned.translation)},
      {"object_error", number_or_null(aligned.object_error)},
      {"robots", aligned.robots},
      {"poses", aligned.poses},
  };
  if (metrics.association) {
    const AssociationMetrics& a = *metrics.association;
    document["association"] = {
        {"linked_pairs", a.linked_pairs},
        {"correct_pairs", a.correct_pairs},
        {"precision", number_or_null(a.precision)},
        {"common_objects", a.common_objects},
        {"found", a.found},
        {"recall", number_or_null(a.recall)},
        {"common_objects_aligned", a.common_objects_aligned},
        {"found_aligned", a.found_aligned},
        {"recall_aligned", number_or_null(a.recall_aligned)},
        {"pairs_in_one_frame", a.pairs_in_one_frame},
        {"robot_pairs", a.robot_pairs},
    };
  }
  return document;
}

std::string format_table(const TeamMetrics& metrics, const std::string& title) {
  constexpr int kLabelWidth = 10;
  constexpr int kColumnWidth = 16;
  char line[512];
  std::ostringstream table;
  table << title << '\n';
  std::snprintf(line, sizeof(line), "%-*s%*s%*s%*s%*s%*s\n", kLabelWidth, "", kColumnWidth,
                "traj RMSE m", kColumnWidth, "odom RMSE m", kColumnWidth, "object err m",
                kColumnWidth, "disagreement m", kColumnWidth, "objects");
  table << line;
  const auto write_row = [&](const std::string& label, const RobotMetrics& row) {
    std::snprintf(line, sizeof(line), "%-*s%*s%*s%*s%*s%*d\n", kLabelWidth, label.c_str(),
                  kColumnWidth, format_metres(row.trajectory_rmse).c_str(), kColumnWidth,
                  format_metres(row.odometry_rmse).c_str(), kColumnWidth,
                  format_metres(row.object_error).c_str(), kColumnWidth,
                  format_metres(row.disagreement).c_str(), kColumnWidth, row.objects_evaluated);
    table << line;
  };
  for (const RobotMetrics& robot : metrics.robots) {
    write_row("Robot " + std::to_string(robot.robot), robot);
  }
  write_row("Avg", metrics.average);
  write_row("Max", metrics.maximum);

  if (metrics.association) {
    const AssociationMetrics& a = *metrics.association;
    std::snprintf(line, sizeof(line),
                  "association: precision %s (%d of %d linked pairs), recall %s (%d of %d common "
                  "objects), %s for robots in one frame; %d of %d robot pairs in one frame\n",
                  format_metres(a.precision).c_str(), a.correct_pairs, a.linked_pairs,
                  format_metres(a.recall).c_str(), a.found, a.common_objects,
                  format_metres(a.recall_aligned).c_str(), a.pairs_in_one_frame, a.robot_pairs);
    table << line;
  }
  if (metrics.team_aligned.poses >= 3) {
    const TeamAlignedMetrics& aligned = metrics.team_aligned;
    std::snprintf(line, sizeof(line),
                  "team trajectory RMSE after one rigid fit of the %d robots in robot 0's frame: "
                  "%s m, object error %s m (the fit: %s deg, %s m)\n",
                  aligned.robots, format_metres(aligned.trajectory_rmse).c_str(),
                  format_metres(aligned.object_error).c_str(),
                  format_metres(aligned.rotation_degrees).c_str(),
                  format_metres(aligned.translation).c_str());
    table << line;
  }
  for (const RobotMetrics& robot : metrics.robots) {
    if (!robot.moved) continue;
    std::snprintf(line, sizeof(line),
                  "Robot %d aligned at frame %d: T_team_own error %s m / %s deg (NEES %s, 6-D), "
                  "pose error there %s m / %s deg; traj RMSE from frame %d: %s m\n",
                  robot.robot, robot.aligned_at_frame,
                  format_metres(robot.alignment_translation_error).c_str(),
                  format_metres(robot.alignment_rotation_error_degrees).c_str(),
                  format_metres(robot.alignment_nees).c_str(),
                  format_metres(robot.aligned_pose_error).c_str(),
                  format_metres(robot.aligned_pose_rotation_error_degrees).c_str(),
                  robot.first_frame, format_metres(robot.trajectory_rmse_aligned).c_str());
    table << line;
  }

  bool any_nees = false;
  for (const RobotMetrics& robot : metrics.robots) {
    any_nees = any_nees || robot.pose_nees.samples > 0 || robot.object_nees.samples > 0;
  }
  if (!any_nees) return table.str();
  // Consistency: mean / median / fraction inside the 95 % bound of each NEES.
  table << "NEES (mean / median / inside 95 %; consistent: mean near dof, about 95 % inside)\n";
  std::snprintf(line, sizeof(line), "%-*s%*s%*s%*s%*s\n", kLabelWidth, "", 22, "pose (6-D)", 22,
                "position (3-D)", 22, "orientation (3-D)", 22, "object (3-D)");
  table << line;
  const auto format_nees = [](const NeesSummary& nees) {
    if (nees.samples == 0) return std::string("-");
    char text[64];
    std::snprintf(text, sizeof(text), "%.2f / %.2f / %.0f%%", nees.mean, nees.median,
                  100.0 * nees.inside_95);
    return std::string(text);
  };
  const auto write_nees_row = [&](const std::string& label, const RobotMetrics& row) {
    std::snprintf(line, sizeof(line), "%-*s%*s%*s%*s%*s\n", kLabelWidth, label.c_str(), 22,
                  format_nees(row.pose_nees).c_str(), 22, format_nees(row.position_nees).c_str(),
                  22, format_nees(row.orientation_nees).c_str(), 22,
                  format_nees(row.object_nees).c_str());
    table << line;
  };
  for (const RobotMetrics& robot : metrics.robots) {
    write_nees_row("Robot " + std::to_string(robot.robot), robot);
  }
  write_nees_row("Avg", metrics.average);
  return table.str();
}

}  // namespace concord::evaluation
