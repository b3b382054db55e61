#include "concord/association/map_description.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cassert>

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
  constexpr std::size_t kHeader = 12;
  constexpr std::size_t kPerObject = 8 + 2 + 2 + 1 + 15 * 4;
  return kHeader + kPerObject * objects.size();
}

void ObservationTally::add(const std::vector<StereoObservation>& observations,
                           const std::vector<int>& classes) {
  for (std::size_t n = 0; n < observations.size(); ++n) {
    Entry& entry = entries_[observations[n].id];
    ++entry.frames;
    if (n < classes.size()) ++entry.votes[classes[n]];
  }
}

int ObservationTally::observations(LandmarkId id) const {
  const auto it = entries_.find(id);
  return it == entries_.end() ? 0 : it->second.frames;
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
                            int min_observations, bool archived_local) {
  MapDescription description;
  description.robot = robot;
  description.frame = frame;
  // The object relative to the robot's current pose (kept as the marginal when round-off made the
  // conditional indefinite).
  const NewestPoseConditioning conditioning(state);
  for (const ObjectEstimate& object : state.objects()) {
    const int observations = tally.observations(object.id);
    if (observations < min_observations) continue;
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
    if (slot < 0 && archived_local) {
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
