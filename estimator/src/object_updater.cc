#include "concord/estimator/object_updater.h"

#include <Eigen/QR>
#include <cmath>

#include "concord/estimator/state_helper.h"

namespace concord {

ObjectUpdater::ObjectUpdater(const EstimatorOptions& options, const StereoCamera& camera)
    : options_(options), camera_(camera) {
  const double sigma = options.object_sigma / camera.focal_length();
  noise_variance_ = sigma * sigma;
  chi2_threshold_4dof_ = options.object_chi2_probability > 0.0
                             ? UpdaterHelper::chi2_quantile(options.object_chi2_probability, 4)
                             : 0.0;
}

bool ObjectUpdater::passes_gates(const State& state, const LinearizedTrack& linearized) const {
  if (options_.object_update_gate > 0.0) {
    const double largest = linearized.residual.cwiseAbs().maxCoeff() * camera_.focal_length();
    if (largest > options_.object_update_gate) return false;
  }
  if (chi2_threshold_4dof_ > 0.0) {
    const Eigen::MatrixXd noise =
        noise_variance_ *
        Eigen::MatrixXd::Identity(linearized.residual.size(), linearized.residual.size());
    if (StateHelper::mahalanobis_squared(state, linearized.H_state, linearized.residual, noise) >
        chi2_threshold_4dof_) {
      return false;
    }
  }
  return true;
}

ObjectUpdateStats ObjectUpdater::process(State& state,
                                         const std::vector<StereoObservation>& objects) {
  ObjectUpdateStats stats;
  const int frame = state.newest_pose().frame;
  const Eigen::Isometry3d& T_world_body = state.newest_pose().T_world_body;

  // 1. Collect gated observations of in-state objects (archived ones rejoin the state first).
  std::vector<LinearizedTrack> accepted;
  int accepted_rows = 0;
  for (const StereoObservation& observation : objects) {
    ++stats.observations;
    const TrackObservation track_observation{frame, camera_.normalize(observation.uv)};
    if (state.landmark_slot(observation.id) < 0) {
      const auto archived = state.archived.find(observation.id);
      if (archived == state.archived.end()) {
        pending_[observation.id].push_back(track_observation);
        continue;
      }
      // Rejoin only if the archived estimate projects plausibly; else treat as outlier.
      const auto projection =
          UpdaterHelper::project(camera_, T_world_body, archived->second.p_world);
      if (!projection) {
        ++stats.rejected;
        continue;
      }
      StateHelper::insert_independent_landmark(state, archived->second, frame);
      state.archived.erase(archived);
      state.archived_last_observed.erase(observation.id);
      ++stats.reactivated;
    }
    const int slot = state.landmark_slot(observation.id);
    const auto linearized = UpdaterHelper::linearize(state, camera_, {track_observation},
                                                     state.landmarks[slot].p_world, slot);
    if (!linearized || !passes_gates(state, *linearized)) {
      ++stats.rejected;
      continue;
    }
    state.landmarks[slot].last_observed_frame = frame;
    accepted_rows += static_cast<int>(linearized->residual.size());
    accepted.push_back(*linearized);
    ++stats.updated;
  }

  // 2. One stacked Kalman update for all accepted object observations (eq. 26-28).
  if (!accepted.empty()) {
    // Linearizations were taken before other objects rejoined: widen to the final dimension.
    Eigen::MatrixXd H = Eigen::MatrixXd::Zero(accepted_rows, state.dimension());
    Eigen::VectorXd residual(accepted_rows);
    int row = 0;
    for (const LinearizedTrack& linearized : accepted) {
      const auto rows = linearized.residual.size();
      H.block(row, 0, rows, linearized.H_state.cols()) = linearized.H_state;
      residual.segment(row, rows) = linearized.residual;
      row += static_cast<int>(rows);
    }
    const Eigen::MatrixXd noise = noise_variance_ * Eigen::MatrixXd::Identity(row, row);
    StateHelper::update(state, H, residual, noise);
  }

  // 3. Initialize objects with enough observations in the window (§V-E).
  const int oldest_frame = state.poses.front().frame;
  for (auto it = pending_.begin(); it != pending_.end();) {
    auto& track = it->second;
    std::erase_if(track, [&](const TrackObservation& o) { return o.frame < oldest_frame; });
    if (track.empty()) {
      it = pending_.erase(it);
      continue;
    }
    const bool observed_now = track.back().frame == frame;
    if (observed_now && static_cast<int>(track.size()) >= options_.object_min_observations) {
      if (try_initialize(state, it->first, track)) {
        ++stats.initialized;
        it = pending_.erase(it);
        continue;
      }
      ++stats.init_failed;
    }
    ++it;
  }

  // 4. Bound the joint state.
  archive_stale(state, frame, stats);
  return stats;
}

bool ObjectUpdater::try_initialize(State& state, LandmarkId id,
                                   const std::vector<TrackObservation>& track) {
  std::vector<Eigen::Isometry3d> poses;
  std::vector<Eigen::Vector4d> observations;
  for (const TrackObservation& observation : track) {
    const int slot = state.pose_slot(observation.frame);
    if (slot < 0) continue;
    poses.push_back(state.poses[slot].T_world_body);
    observations.push_back(observation.xy);
  }
  // 1. Stereo triangulation and refinement over the window's observations.
  const auto p_world = UpdaterHelper::triangulate(camera_, poses, observations);
  if (!p_world) return false;
  // 2. Rejection on reprojection error, cheirality and distance.
  const double rms = UpdaterHelper::rms_reprojection_error(camera_, poses, observations, *p_world) *
                     camera_.focal_length();
  if (!(rms <= options_.object_init_max_reprojection_error)) return false;
  const auto newest = UpdaterHelper::project(camera_, poses.back(), *p_world);
  if (!newest || newest->depth_left < options_.object_min_distance ||
      newest->depth_left > options_.object_max_distance) {
    return false;
  }
  // 3. Linearize and split with QR (eq. 29): Q^T H_point = [R1; 0].
  auto linearized = UpdaterHelper::linearize(state, camera_, track, *p_world);
  if (!linearized) return false;
  const Eigen::Index rows = linearized->residual.size();
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(linearized->H_point);
  const Eigen::MatrixXd Qt = qr.householderQ().transpose();
  const Eigen::MatrixXd H_state_rotated = Qt * linearized->H_state;
  const Eigen::VectorXd residual_rotated = Qt * linearized->residual;
  const Eigen::Matrix3d R1 =
      qr.matrixQR().topLeftCorner<3, 3>().triangularView<Eigen::Upper>().toDenseMatrix();
  if (std::abs(R1.determinant()) < 1e-12) return false;

  // 4. Augment (eq. 30), then update with the rows that do not involve the new object.
  const Eigen::Vector3d p_new = *p_world + R1.inverse() * residual_rotated.head<3>();
  const Eigen::Matrix3d noise1 = noise_variance_ * Eigen::Matrix3d::Identity();
  StateHelper::augment_landmark(state, id, p_new, track.back().frame, H_state_rotated.topRows(3),
                                R1, noise1);
  if (rows > 3) {
    Eigen::MatrixXd H2 = Eigen::MatrixXd::Zero(rows - 3, state.dimension());
    H2.leftCols(H_state_rotated.cols()) = H_state_rotated.bottomRows(rows - 3);
    const Eigen::VectorXd r2 = residual_rotated.tail(rows - 3);
    const Eigen::MatrixXd noise2 = noise_variance_ * Eigen::MatrixXd::Identity(rows - 3, rows - 3);
    StateHelper::update(state, H2, r2, noise2);
  }
  return true;
}

void ObjectUpdater::archive_stale(State& state, int frame, ObjectUpdateStats& stats) const {
  if (options_.object_archive_after_frames <= 0) return;
  std::vector<int> stale;
  for (int slot = 0; slot < state.num_landmarks(); ++slot) {
    if (frame - state.landmarks[slot].last_observed_frame > options_.object_archive_after_frames) {
      stale.push_back(slot);
    }
  }
  if (stale.empty()) return;
  for (int slot : stale) {
    const auto& landmark = state.landmarks[slot];
    const int index = state.landmark_index(slot);
    state.archived[landmark.id] = {landmark.id, landmark.p_world,
                                   state.covariance.block<3, 3>(index, index)};
    state.archived_last_observed[landmark.id] = landmark.last_observed_frame;
  }
  StateHelper::remove_landmarks(state, stale);
  stats.archived += static_cast<int>(stale.size());
}

}  // namespace concord
