#include "concord/association/map_description.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cassert>
#include <cmath>

#include "concord/estimator/pose_conditioning.h"

namespace concord::association {

namespace {
constexpr int kIdBits = 40;
constexpr std::int64_t kIdMask = (std::int64_t{1} << kIdBits) - 1;
}  // namespace

ObjectKey object_key(int robot, LandmarkId id) {
  assert(robot >= 0 && robot < (1 << 23) && id >= 0 && id <= kIdMask);
  return (static_cast<std::int64_t>(robot) << kIdBits) | id;
}

int robot_of(ObjectKey key) { return static_cast<int>(key >> kIdBits); }

LandmarkId id_of(ObjectKey key) { return key & kIdMask; }

std::size_t MapDescription::wire_size() const {
  constexpr std::size_t kHeader = 16 + 21 * 4;
  constexpr std::size_t kPerObject = 8 + 2 + 2 + 1 + 15 * 4;
  return kHeader + kPerObject * objects.size();
}

namespace {

/// The depth histogram's range and resolution: log-spaced bins from kDepthLow to kDepthHigh.
constexpr double kDepthLow = 0.05, kDepthHigh = 500.0;
constexpr int kDepthBins = 128;

int depth_bin(double depth) {
  const double position = std::log(depth / kDepthLow) / std::log(kDepthHigh / kDepthLow);
  return std::clamp(static_cast<int>(position * kDepthBins), 0, kDepthBins - 1);
}

/// The lower edge of bin b.
double bin_depth(int bin) {
  return kDepthLow * std::pow(kDepthHigh / kDepthLow, static_cast<double>(bin) / kDepthBins);
}

}  // namespace

void ObservationTally::add(const std::vector<StereoObservation>& observations,
                           const std::vector<int>& classes, const State& state,
                           const StereoCamera& camera) {
  ++frames_added_;
  for (std::size_t n = 0; n < observations.size(); ++n) {
    Entry& entry = entries_[observations[n].id];
    ++entry.frames;
    entry.last_detected = frames_added_;
    if (n < classes.size()) ++entry.votes[classes[n]];
  }

  // 1. The view: the detections' extent in the left image and their depths (a histogram: a
  //    depth from a far detection's small disparity is noisy, and the range is taken between its
  //    5 % and 95 % quantiles, the near one rounded up and the far one down to a bin edge).
  const double baseline = camera.baseline();
  if (depth_histogram_.empty()) depth_histogram_.assign(kDepthBins, 0);
  for (const StereoObservation& observation : observations) {
    const Eigen::Vector4d xy = camera.normalize(observation.uv);
    if (!xy.allFinite()) continue;
    if (!view_known_) {
      view_min_ = view_max_ = xy.head<2>();
      view_known_ = true;
    } else {
      view_min_ = view_min_.cwiseMin(xy.head<2>());
      view_max_ = view_max_.cwiseMax(xy.head<2>());
    }
    const double disparity = xy(0) - xy(2);
    const double depth = disparity > 0.0 ? baseline / disparity : 0.0;
    if (std::isfinite(depth) && depth > 0.0) {
      ++depth_histogram_[static_cast<std::size_t>(depth_bin(depth))];
      ++depths_;
    }
  }
  if (!view_known_ || depths_ < 20 || state.num_poses() == 0) return;
  double near = 0.0, far = 0.0;
  long long below = 0;
  for (int b = 0; b < kDepthBins; ++b) {
    const long long count = depth_histogram_[static_cast<std::size_t>(b)];
    if (below < depths_ / 20 && below + count >= depths_ / 20) near = bin_depth(b + 1);
    if (below < depths_ - depths_ / 20 && below + count >= depths_ - depths_ / 20)
      far = bin_depth(b);
    below += count;
  }
  if (!(far > near)) return;
  const Eigen::Vector2d margin = 0.1 * (view_max_ - view_min_);
  const Eigen::Vector2d low = view_min_ + margin, high = view_max_ - margin;

  // 2. The misses: objects in that view at the newest pose that this frame did not detect.
  const Eigen::Isometry3d T_cam_world =
      camera.T_cam0_body * state.newest_pose().T_world_body.inverse();
  const auto look_at = [&](LandmarkId id, const Eigen::Vector3d& p_world) {
    const Eigen::Vector3d p = T_cam_world * p_world;
    if (!(p.z() >= near && p.z() <= far)) return;
    const Eigen::Vector2d x = p.head<2>() / p.z();
    if (!(x.array() >= low.array()).all() || !(x.array() <= high.array()).all()) return;
    const auto it = entries_.find(id);
    if (it != entries_.end() && it->second.last_detected != frames_added_) ++it->second.misses;
  };
  for (const ObjectLandmark& landmark : state.landmarks) {
    if (!landmark.detection_offset) look_at(landmark.id, landmark.p_world);
  }
  for (const auto& [id, estimate] : state.archived) look_at(id, estimate.p_world);
}

int ObservationTally::observations(LandmarkId id) const {
  const auto it = entries_.find(id);
  return it == entries_.end() ? 0 : it->second.frames;
}

int ObservationTally::misses(LandmarkId id) const {
  const auto it = entries_.find(id);
  return it == entries_.end() ? 0 : it->second.misses;
}

int ObservationTally::object_class(LandmarkId id) const {
  const auto it = entries_.find(id);
  if (it == entries_.end() || it->second.votes.empty()) return kUnknownClass;
  int best = kUnknownClass, most = 0;
  for (const auto& [object_class, votes] : it->second.votes) {
    if (votes > most) {
      best = object_class;
      most = votes;
    }
  }
  return best;
}

MapDescription describe_map(const State& state, int robot, int frame, const ObservationTally& tally,
                            int min_observations, double min_detection_ratio) {
  MapDescription description;
  description.robot = robot;
  description.frame = frame;
  const int pose = state.pose_index(state.num_poses() - 1);
  description.pose_frame = state.newest_pose().frame;
  description.pose_covariance = state.covariance.block<6, 6>(pose, pose);
  description.pose_covariance =
      0.5 * (description.pose_covariance + description.pose_covariance.transpose()).eval();
  // The object relative to the robot's current pose (kept as the marginal when round-off made the
  // conditional indefinite).
  const NewestPoseConditioning conditioning(state);
  for (const ObjectEstimate& object : state.objects()) {
    const int observations = tally.observations(object.id);
    if (observations < min_observations) continue;
    const int misses = tally.misses(object.id);
    if (static_cast<double>(observations) <
        min_detection_ratio * static_cast<double>(observations + misses)) {
      continue;
    }
    ObjectDescription entry;
    entry.id = object.id;
    entry.object_class = tally.object_class(object.id);
    entry.position = object.p_world;
    entry.covariance = 0.5 * (object.covariance + object.covariance.transpose());
    // An object whose covariance round-off made indefinite cannot be compared (and a neighbour
    // would refuse the description): left out.
    if (Eigen::LLT<Eigen::Matrix3d>(entry.covariance).info() != Eigen::Success) continue;
    entry.local_covariance = entry.covariance;
    entry.observations = observations;
    const int slot = state.landmark_slot(object.id);
    entry.archived = slot < 0;
    if (slot < 0) {
      // Archived: what the robot knew of it relative to itself when it archived it, unless
      // consensus has since made the marginal itself the smaller (a relative uncertainty cannot
      // exceed the marginal).
      const auto local = state.archived_local_covariance.find(object.id);
      if (local != state.archived_local_covariance.end() &&
          Eigen::LDLT<Eigen::Matrix3d>(entry.covariance - local->second).isPositive()) {
        entry.local_covariance = local->second;
      }
    }
    if (slot >= 0) {
      const auto local = conditioning.of(state.landmark_index(slot), entry.covariance);
      if (local) entry.local_covariance = *local;
    }
    description.objects.push_back(entry);
  }
  return description;
}

}  // namespace concord::association
