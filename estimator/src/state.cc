#include "concord/estimator/state.h"

#include <algorithm>

namespace concord {

WorldUp WorldUp::around(const Eigen::Vector3d& reference) {
  WorldUp up;
  up.reference = reference.normalized();
  up.basis.col(0) = up.reference.unitOrthogonal();
  up.basis.col(1) = up.reference.cross(up.basis.col(0));
  return up;
}

Eigen::Vector3d WorldUp::direction() const { return (reference + basis * tilt).normalized(); }

Eigen::Matrix<double, 3, 2> WorldUp::jacobian() const {
  const Eigen::Vector3d v = reference + basis * tilt;
  const Eigen::Vector3d u = v.normalized();
  return (Eigen::Matrix3d::Identity() - u * u.transpose()) * basis / v.norm();
}

int State::pose_slot(int frame) const {
  // Poses are consecutive frames, oldest first.
  if (poses.empty()) return -1;
  const int slot = frame - poses.front().frame;
  if (slot < 0 || slot >= num_poses() || poses[slot].frame != frame) return -1;
  return slot;
}

int State::landmark_slot(LandmarkId id) const {
  const auto it = landmark_slots_.find(id);
  return it == landmark_slots_.end() ? -1 : it->second;
}

int State::offset_slot(LandmarkId id) const {
  const auto it = offset_slots_.find(id);
  return it == offset_slots_.end() ? -1 : it->second;
}

void State::rebuild_landmark_index() {
  landmark_slots_.clear();
  offset_slots_.clear();
  for (int slot = 0; slot < num_landmarks(); ++slot) {
    (landmarks[slot].detection_offset ? offset_slots_ : landmark_slots_)[landmarks[slot].id] = slot;
  }
}

std::vector<LandmarkId> State::object_ids() const {
  std::vector<LandmarkId> ids;
  ids.reserve(landmarks.size() + archived.size());
  for (const auto& landmark : landmarks) {
    if (!landmark.detection_offset) ids.push_back(landmark.id);
  }
  for (const auto& [id, estimate] : archived) ids.push_back(id);
  std::sort(ids.begin(), ids.end());
  return ids;
}

std::vector<ObjectEstimate> State::objects() const {
  std::vector<ObjectEstimate> out;
  out.reserve(landmarks.size() + archived.size());
  for (int slot = 0; slot < num_landmarks(); ++slot) {
    if (landmarks[slot].detection_offset) continue;
    const int index = landmark_index(slot);
    out.push_back(
        {landmarks[slot].id, landmarks[slot].p_world, covariance.block<3, 3>(index, index)});
  }
  for (const auto& [id, estimate] : archived) out.push_back(estimate);
  std::sort(out.begin(), out.end(),
            [](const ObjectEstimate& a, const ObjectEstimate& b) { return a.id < b.id; });
  return out;
}

}  // namespace concord
