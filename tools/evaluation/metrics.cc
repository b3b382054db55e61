#include "evaluation/metrics.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <stdexcept>

namespace concord::evaluation {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// A robot's object estimates by id; rejects ids listed twice.
std::map<LandmarkId, Eigen::Vector3d> objects_by_id(const RobotResult& result, int robot) {
  std::map<LandmarkId, Eigen::Vector3d> positions;
  for (const ObjectEstimate& object : result.objects) {
    if (!positions.emplace(object.id, object.p_world).second) {
      throw std::invalid_argument("robot " + std::to_string(robot) + " lists object " +
                                  std::to_string(object.id) + " more than once");
    }
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
    const std::size_t odometry_length = truths[robot].odometry.size();
    if (odometry_length != 0 && odometry_length + 1 != truth_length) {
      throw std::invalid_argument("robot " + std::to_string(robot) + ": odometry has " +
                                  std::to_string(odometry_length) + " entries, ground truth has " +
                                  std::to_string(truth_length) + " poses (expected one fewer)");
    }
  }
}

/// Mean ||p_est - p_gt|| over the estimated objects that have ground truth (Table II).
void fill_object_error(const std::map<LandmarkId, Eigen::Vector3d>& estimated,
                       const std::map<LandmarkId, Eigen::Vector3d>& objects_groundtruth,
                       RobotMetrics& metrics) {
  double error_sum = 0.0;
  int count = 0;
  for (const auto& [id, p_world] : estimated) {
    const auto truth = objects_groundtruth.find(id);
    if (truth == objects_groundtruth.end()) continue;
    error_sum += (p_world - truth->second).norm();
    ++count;
  }
  metrics.objects_evaluated = count;
  metrics.object_error = count > 0 ? error_sum / count : kNaN;
}

/// Mean ||p_i - p_j|| over every (object, other robot j) pair where robot j also holds the object
/// (Table III).
void fill_disagreement(const std::vector<std::map<LandmarkId, Eigen::Vector3d>>& estimated,
                       std::size_t robot, RobotMetrics& metrics) {
  double distance_sum = 0.0;
  int pairs = 0;
  for (const auto& [id, p_world] : estimated[robot]) {
    for (std::size_t other = 0; other < estimated.size(); ++other) {
      if (other == robot) continue;
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

nlohmann::json robot_to_json(const RobotMetrics& metrics) {
  return {
      {"robot", metrics.robot},
      {"trajectory_rmse", number_or_null(metrics.trajectory_rmse)},
      {"odometry_rmse", number_or_null(metrics.odometry_rmse)},
      {"object_error", number_or_null(metrics.object_error)},
      {"objects_evaluated", metrics.objects_evaluated},
      {"disagreement", number_or_null(metrics.disagreement)},
      {"disagreement_pairs", metrics.disagreement_pairs},
      {"frames", metrics.frames},
  };
}

/// Fixed 3 decimals, "-" for NaN.
std::string format_metres(double value) {
  if (std::isnan(value)) return "-";
  char text[32];
  std::snprintf(text, sizeof(text), "%.3f", value);
  return text;
}

}  // namespace

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

TeamMetrics evaluate(const std::vector<RobotTruth>& truths, const std::vector<RobotResult>& results,
                     const std::map<LandmarkId, Eigen::Vector3d>& objects_groundtruth) {
  check_inputs(truths, results);

  std::vector<std::map<LandmarkId, Eigen::Vector3d>> estimated_objects;
  estimated_objects.reserve(results.size());
  for (std::size_t robot = 0; robot < results.size(); ++robot) {
    estimated_objects.push_back(objects_by_id(results[robot], static_cast<int>(robot)));
  }

  TeamMetrics team;
  for (std::size_t robot = 0; robot < truths.size(); ++robot) {
    const RobotTruth& truth = truths[robot];
    RobotMetrics metrics;
    metrics.robot = static_cast<int>(robot);
    metrics.frames = static_cast<int>(truth.groundtruth.size());
    // 1. Trajectory RMSE without alignment (Table I).
    metrics.trajectory_rmse = translation_rmse(results[robot].trajectory, truth.groundtruth);
    // 2. The dead-reckoning baseline from the known start pose.
    if (!truth.odometry.empty()) {
      metrics.odometry_rmse = translation_rmse(
          dead_reckoning(truth.groundtruth.front(), truth.odometry), truth.groundtruth);
    }
    // 3. Object error against ground truth (Table II).
    fill_object_error(estimated_objects[robot], objects_groundtruth, metrics);
    // 4. Object position differences across robots (Table III).
    fill_disagreement(estimated_objects, robot, metrics);
    team.robots.push_back(metrics);
  }

  team.average.robot = -1;
  team.maximum.robot = -1;
  for (double RobotMetrics::*field : {&RobotMetrics::trajectory_rmse, &RobotMetrics::odometry_rmse,
                                      &RobotMetrics::object_error, &RobotMetrics::disagreement}) {
    aggregate(team.robots, field, team.average, team.maximum);
  }
  for (int RobotMetrics::*field : {&RobotMetrics::objects_evaluated,
                                   &RobotMetrics::disagreement_pairs, &RobotMetrics::frames}) {
    aggregate(team.robots, field, team.average, team.maximum);
  }
  return team;
}

nlohmann::json to_json(const TeamMetrics& metrics) {
  nlohmann::json robots = nlohmann::json::array();
  for (const RobotMetrics& robot : metrics.robots) robots.push_back(robot_to_json(robot));
  return {
      {"robots", robots},
      {"average", robot_to_json(metrics.average)},
      {"maximum", robot_to_json(metrics.maximum)},
  };
}

std::string format_table(const TeamMetrics& metrics, const std::string& title) {
  constexpr int kLabelWidth = 10;
  constexpr int kColumnWidth = 16;
  char line[256];
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
  return table.str();
}

}  // namespace concord::evaluation
