#include "evaluation/frontend_metrics.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <unordered_map>

#include "concord/estimator/lie.h"
#include "evaluation/metrics.h"

namespace concord::evaluation {

namespace {

/// Pixel position of a point in the left camera frame under K.
Eigen::Vector2d project(const Eigen::Matrix3d& K, const Eigen::Vector3d& p) {
  return Eigen::Vector2d(K(0, 0) * p.x() / p.z() + K(0, 2), K(1, 1) * p.y() / p.z() + K(1, 2));
}

}  // namespace

ErrorStatistics error_statistics(std::vector<double> values) {
  ErrorStatistics statistics;
  statistics.count = static_cast<long long>(values.size());
  if (values.empty()) return statistics;
  std::sort(values.begin(), values.end());
  const auto at = [&](double p) {
    const auto rank = static_cast<std::size_t>(std::ceil(p / 100.0 * values.size()));
    return values[std::clamp<std::size_t>(rank, 1, values.size()) - 1];
  };
  statistics.median = at(50);
  statistics.p90 = at(90);
  statistics.max = values.back();
  double sum = 0.0;
  for (const double value : values) sum += value;
  statistics.mean = sum / values.size();
  return statistics;
}

OdometryAccuracy odometry_accuracy(const std::vector<Eigen::Isometry3d>& groundtruth,
                                   const std::vector<Eigen::Isometry3d>& odometry,
                                   const std::vector<Eigen::Matrix<double, 6, 6>>& covariances) {
  if (groundtruth.empty() || odometry.size() + 1 != groundtruth.size()) {
    throw std::invalid_argument("odometry_accuracy: need one motion fewer than poses");
  }
  if (!covariances.empty() && covariances.size() != odometry.size()) {
    throw std::invalid_argument("odometry_accuracy: need one covariance per motion");
  }
  OdometryAccuracy accuracy;
  accuracy.motions = static_cast<int>(odometry.size());
  const std::vector<Eigen::Isometry3d> reckoned = dead_reckoning(groundtruth.front(), odometry);
  double squared_sum = 0.0, translation_sum = 0.0, rotation_sum = 0.0, nees_sum = 0.0;
  for (std::size_t frame = 0; frame < groundtruth.size(); ++frame) {
    const double error = (reckoned[frame].translation() - groundtruth[frame].translation()).norm();
    squared_sum += error * error;
    accuracy.max_error = std::max(accuracy.max_error, error);
    if (frame == 0) continue;
    accuracy.path_length +=
        (groundtruth[frame].translation() - groundtruth[frame - 1].translation()).norm();
    const Eigen::Isometry3d truth = groundtruth[frame - 1].inverse() * groundtruth[frame];
    const lie::Vector6d xi = lie::se3_log(truth.inverse() * odometry[frame - 1]);
    translation_sum += xi.head<3>().squaredNorm();
    rotation_sum += xi.tail<3>().squaredNorm();
    if (!covariances.empty()) {
      nees_sum += xi.dot(covariances[frame - 1].ldlt().solve(xi));
    }
  }
  accuracy.final_error = (reckoned.back().translation() - groundtruth.back().translation()).norm();
  accuracy.final_error_percent =
      accuracy.path_length > 0.0 ? 100.0 * accuracy.final_error / accuracy.path_length : 0.0;
  accuracy.rmse = std::sqrt(squared_sum / groundtruth.size());
  if (accuracy.motions > 0) {
    accuracy.translation_error_rms = std::sqrt(translation_sum / accuracy.motions);
    accuracy.rotation_error_rms = std::sqrt(rotation_sum / accuracy.motions);
    if (!covariances.empty()) accuracy.nees_mean = nees_sum / accuracy.motions;
  }
  return accuracy;
}

TrackAccuracy track_accuracy(const sim::TexturedWorld& world, const StereoCamera& camera,
                             const std::vector<Eigen::Isometry3d>& groundtruth,
                             const std::vector<std::vector<StereoObservation>>& features) {
  TrackAccuracy accuracy;
  std::unordered_map<LandmarkId, std::optional<Eigen::Vector3d>> points;  // world, per track
  std::vector<double> left, right, all;
  const Eigen::Matrix3d K_inverse = camera.K.inverse();
  for (std::size_t frame = 0; frame < features.size() && frame < groundtruth.size(); ++frame) {
    const Eigen::Isometry3d T_world_cam0 = groundtruth[frame] * camera.T_cam0_body.inverse();
    const Eigen::Isometry3d T_cam0_world = T_world_cam0.inverse();
    const Eigen::Isometry3d T_cam1_world = camera.T_cam0_cam1.inverse() * T_cam0_world;
    for (const StereoObservation& observation : features[frame]) {
      auto [entry, first] = points.try_emplace(observation.id);
      if (first) {
        ++accuracy.tracks;
        const Eigen::Vector3d ray =
            T_world_cam0.linear() *
            (K_inverse * Eigen::Vector3d(observation.uv(0), observation.uv(1), 1.0));
        if (const auto hit = world.cast(T_world_cam0.translation(), ray)) {
          entry->second = T_world_cam0.translation() + hit->distance * ray;
        } else {
          ++accuracy.unanchored;
        }
      }
      if (!entry->second) continue;
      const Eigen::Vector3d p_cam0 = T_cam0_world * *entry->second;
      const Eigen::Vector3d p_cam1 = T_cam1_world * *entry->second;
      if (p_cam0.z() <= 0.0 || p_cam1.z() <= 0.0) continue;
      const double right_error = (project(camera.K, p_cam1) - observation.uv.tail<2>()).norm();
      right.push_back(right_error);
      all.push_back(right_error);
      if (!first) {
        const double left_error = (project(camera.K, p_cam0) - observation.uv.head<2>()).norm();
        left.push_back(left_error);
        all.push_back(left_error);
      }
    }
  }
  accuracy.left = error_statistics(std::move(left));
  accuracy.right = error_statistics(std::move(right));
  accuracy.all = error_statistics(std::move(all));
  return accuracy;
}

ObjectObservationAccuracy object_observation_accuracy(
    const StereoCamera& camera, const std::vector<Eigen::Isometry3d>& groundtruth,
    const std::vector<std::vector<StereoObservation>>& objects,
    const std::map<LandmarkId, Eigen::Vector3d>& objects_groundtruth) {
  std::vector<double> centre, disparity, depth;
  const double focal_baseline = camera.K(0, 0) * camera.baseline();
  for (std::size_t frame = 0; frame < objects.size() && frame < groundtruth.size(); ++frame) {
    const Eigen::Isometry3d T_cam0_world = camera.T_cam0_body * groundtruth[frame].inverse();
    for (const StereoObservation& observation : objects[frame]) {
      const auto truth = objects_groundtruth.find(observation.id);
      if (truth == objects_groundtruth.end()) continue;
      const Eigen::Vector3d p = T_cam0_world * truth->second;
      if (p.z() <= 0.0) continue;
      centre.push_back((project(camera.K, p) - observation.uv.head<2>()).norm());
      const double true_disparity = focal_baseline / p.z();
      const double observed_disparity = observation.uv(0) - observation.uv(2);
      disparity.push_back(std::abs(observed_disparity - true_disparity));
      if (observed_disparity > 0.0) {
        depth.push_back(std::abs(focal_baseline / observed_disparity - p.z()) / p.z());
      }
    }
  }
  return {error_statistics(std::move(centre)), error_statistics(std::move(disparity)),
          error_statistics(std::move(depth))};
}

}  // namespace concord::evaluation
