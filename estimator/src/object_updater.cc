#include "concord/estimator/object_updater.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/QR>
#include <cmath>
#include <limits>

#include "concord/estimator/consensus.h"
#include "concord/estimator/pose_conditioning.h"
#include "concord/estimator/state_helper.h"

namespace concord {

ObjectUpdater::ObjectUpdater(const EstimatorOptions& options, const StereoCamera& camera,
                             PendingObjects pending)
    : options_(options),
      camera_(camera),
      independent_covariance_(UpdaterHelper::observation_covariance(options.object_noise, camera)),
      constant_covariance_(
          UpdaterHelper::observation_covariance(options.object_noise_constant, camera)),
      persistent_covariance_(
          UpdaterHelper::observation_covariance(options.object_noise_persistent, camera)),
      persistent_(!constant_covariance_.isZero(0.0) || !persistent_covariance_.isZero(0.0)),
      pending_(std::move(pending)) {
  whitening_ = UpdaterHelper::whitening(independent_covariance_ + constant_covariance_ +
                                        persistent_covariance_);
  // Image units to normalized: x and disparity by fx, y by fy.
  const auto normalized_variances = [&](const StereoNoise& noise) {
    const double fx = camera.K(0, 0), fy = camera.K(1, 1);
    return Eigen::Vector3d(noise.horizontal / fx, noise.vertical / fy, noise.disparity / fx)
        .cwiseAbs2()
        .eval();
  };
  offset_prior_ = normalized_variances(options.object_offset_sigma);
  offset_walk_ = normalized_variances(options.object_offset_walk);
  const auto& sigma = options.object_displacement_sigma;
  const auto& walk = options.object_displacement_walk;
  displacement_prior_ = Eigen::Vector3d(sigma[0], sigma[1], sigma[2]).cwiseAbs2();
  displacement_walk_ = Eigen::Vector3d(walk[0], walk[1], walk[2]).cwiseAbs2();
  displacement_ =
      options.detection_error_state() == EstimatorOptions::DetectionErrorState::kDisplacement;
}

Eigen::Matrix3d ObjectUpdater::newest_camera_to_world(const State& state,
                                                      const Eigen::Vector3d& variances) const {
  const Eigen::Matrix3d R_world_cam =
      state.newest_pose().T_world_body.linear() * camera_.T_cam0_body.linear().transpose();
  return R_world_cam * variances.asDiagonal() * R_world_cam.transpose();
}

void ObjectUpdater::walk_offsets(State& state) const {
  const Eigen::Matrix3d displacement_walk =
      displacement_ ? newest_camera_to_world(state, displacement_walk_) : Eigen::Matrix3d::Zero();
  for (int slot = 0; slot < state.num_landmarks(); ++slot) {
    if (!state.landmarks[slot].detection_offset) continue;
    const int index = state.landmark_index(slot);
    if (displacement_) {
      state.covariance.block<3, 3>(index, index) += displacement_walk;
    } else {
      state.covariance.block<3, 3>(index, index).diagonal() += offset_walk_;
    }
  }
}

int ObjectUpdater::add_offset(State& state, LandmarkId id, int frame,
                              ObjectUpdateStats& stats) const {
  const int n = state.dimension();
  state.covariance.conservativeResize(n + 3, n + 3);
  state.covariance.rightCols<3>().setZero();
  state.covariance.bottomRows<3>().setZero();
  if (displacement_) {
    state.covariance.block<3, 3>(n, n) = newest_camera_to_world(state, displacement_prior_);
  } else {
    state.covariance.block<3, 3>(n, n).diagonal() = offset_prior_;
  }
  ObjectLandmark offset;
  offset.id = id;
  offset.detection_offset = true;
  offset.displacement = displacement_;
  offset.last_observed_frame = frame;
  state.landmarks.push_back(std::move(offset));
  state.rebuild_landmark_index();
  ++stats.offsets_added;
  return state.num_landmarks() - 1;
}

void ObjectUpdater::apply_offset(const State& state, int offset_slot,
                                 LinearizedTrack& linearized) const {
  const int index = state.landmark_index(offset_slot);
  if (displacement_) {
    // pi(T, p + d) ~ pi(T, p) + H_point d.
    linearized.H_state.middleCols<3>(index) = linearized.H_point;
    linearized.residual -= linearized.H_point * state.landmarks[offset_slot].p_world;
    return;
  }
  // d(u_left, v_left, u_right, v_right) / d(du, dv, dd).
  Eigen::Matrix<double, 4, 3> jacobian;
  jacobian << 1.0, 0.0, 0.0,  //
      0.0, 1.0, 0.0,          //
      1.0, 0.0, -1.0,         //
      0.0, 1.0, 0.0;
  const Eigen::Vector4d predicted = jacobian * state.landmarks[offset_slot].p_world;
  for (Eigen::Index row = 0; row < linearized.residual.size(); row += 4) {
    linearized.residual.segment<4>(row) -= predicted;
    linearized.H_state.block<4, 3>(row, index) = jacobian;
  }
}

Eigen::MatrixXd ObjectUpdater::track_noise(const std::vector<TrackObservation>& track) const {
  const auto count = static_cast<Eigen::Index>(track.size());
  Eigen::MatrixXd covariance(4 * count, 4 * count);
  for (Eigen::Index i = 0; i < count; ++i) {
    for (Eigen::Index j = 0; j < count; ++j) {
      const double correlation =
          std::pow(options_.object_noise_correlation, std::abs(track[i].frame - track[j].frame));
      covariance.block<4, 4>(4 * i, 4 * j) =
          constant_covariance_ + correlation * persistent_covariance_ +
          (i == j ? independent_covariance_ : Eigen::Matrix4d::Zero());
    }
  }
  return covariance;
}

Eigen::Matrix4d ObjectUpdater::first_estimate_noise(
    const State& state, int slot, const Eigen::Matrix<double, 4, 3>& jacobian_point) const {
  const double scale = options_.object_first_estimate_noise;
  const ObjectLandmark& landmark = state.landmarks[slot];
  if (scale == 0.0 || landmark.p_linearization == landmark.p_world) {
    return Eigen::Matrix4d::Zero();
  }
  const int rotation = state.pose_index(state.num_poses() - 1) + 3;
  return scale * UpdaterHelper::first_estimate_noise(
                     jacobian_point, landmark.p_linearization, landmark.p_world,
                     state.covariance.block<3, 3>(rotation, rotation));
}

bool ObjectUpdater::condition_on_earlier(const std::vector<TrackObservation>& track,
                                         LinearizedTrack& linearized,
                                         const Eigen::Matrix4d& added_noise) const {
  // e_new given e_earlier: mean G e_earlier, covariance S_nn - G S_en, G = S_ne S_ee^-1; the
  // rows r_new - G r_earlier (and the same of the Jacobians) carry what the newest observation
  // adds, with that covariance. G and the whitening depend only on the frames' pattern.
  std::vector<int> pattern;
  pattern.reserve(track.size() - 1);
  for (std::size_t i = 0; i + 1 < track.size(); ++i) {
    pattern.push_back(track.back().frame - track[i].frame);
  }
  auto cached = conditionals_.find(pattern);
  if (cached == conditionals_.end()) {
    const Eigen::MatrixXd covariance = track_noise(track);
    const Eigen::Index earlier = covariance.rows() - 4;
    const Eigen::LLT<Eigen::MatrixXd> earlier_factor(covariance.topLeftCorner(earlier, earlier));
    if (earlier_factor.info() != Eigen::Success) return false;
    const Eigen::MatrixXd gain_transposed =
        earlier_factor.solve(covariance.topRightCorner(earlier, 4));  // S_ee^-1 S_en
    const Eigen::Matrix4d conditional =
        covariance.bottomRightCorner<4, 4>() -
        gain_transposed.transpose() * covariance.topRightCorner(earlier, 4);
    const Eigen::LLT<Eigen::Matrix4d> conditional_factor(conditional);
    if (conditional_factor.info() != Eigen::Success) return false;
    if (conditionals_.size() >= 4096) conditionals_.clear();  // bounded; patterns repeat
    cached = conditionals_
                 .emplace(std::move(pattern), Conditional{gain_transposed.transpose(), conditional,
                                                          UpdaterHelper::whitening(conditional)})
                 .first;
  }
  const Conditional& c = cached->second;
  const Eigen::Index earlier = c.gain.cols();
  Eigen::Matrix4d whitening = c.whitening;
  if (!added_noise.isZero(0.0)) {
    const Eigen::Matrix4d covariance = c.covariance + added_noise;
    if (Eigen::LLT<Eigen::Matrix4d>(covariance).info() != Eigen::Success) return false;
    whitening = UpdaterHelper::whitening(covariance);
  }
  const auto condition = [&](const Eigen::MatrixXd& rows) -> Eigen::MatrixXd {
    return whitening * (rows.bottomRows(4) - c.gain * rows.topRows(earlier));
  };
  // Only the track's pose, calibration and landmark columns are not zero.
  const std::vector<int> columns = StateHelper::nonzero_columns(linearized.H_state);
  Eigen::MatrixXd H_state = Eigen::MatrixXd::Zero(4, linearized.H_state.cols());
  H_state(Eigen::all, columns) = condition(linearized.H_state(Eigen::all, columns));
  linearized.H_state = std::move(H_state);
  linearized.H_point = condition(linearized.H_point);
  linearized.residual = condition(linearized.residual);
  linearized.newest_frame_row = 0;
  return true;
}

double ObjectUpdater::gate(int dof) const {
  return options_.object_chi2_probability > 0.0
             ? UpdaterHelper::chi2_quantile(options_.object_chi2_probability, dof)
             : std::numeric_limits<double>::infinity();
}

ObjectUpdateStats ObjectUpdater::process(State& state,
                                         const std::vector<StereoObservation>& objects) {
  ObjectUpdateStats stats;
  const int frame = state.newest_pose().frame;
  const double gate_4dof = gate(4);

  // 0. Detection offsets: each walks a frame; an in-state object observed without one (an
  //    archived consider state seen again) gets one, before any row is linearized against the
  //    state's dimension.
  if (has_offsets()) {
    walk_offsets(state);
    for (const StereoObservation& observation : objects) {
      if (state.landmark_slot(observation.id) >= 0 && state.offset_slot(observation.id) < 0) {
        (void)add_offset(state, observation.id, frame, stats);
      }
    }
  }

  // 1. Collect gated observations of in-state objects. Objects not in the state (new or
  //    archived) wait for initialization.
  std::vector<LinearizedTrack> accepted;
  int accepted_rows = 0;
  for (const StereoObservation& observation : objects) {
    ++stats.observations;
    const TrackObservation track_observation{frame, camera_.normalize(observation.uv)};
    const int slot = state.landmark_slot(observation.id);
    if (slot < 0) {
      pending_[observation.id].push_back(track_observation);
      continue;
    }
    // With a persistent error: the object's earlier observations whose poses are in the window,
    // then this one.
    std::vector<TrackObservation> track;
    if (persistent_) {
      for (const TrackObservation& used : state.landmarks[slot].used_observations) {
        if (used.frame < frame && state.pose_slot(used.frame) >= 0) track.push_back(used);
      }
    }
    track.push_back(track_observation);
    auto linearized =
        UpdaterHelper::linearize(state, camera_, track, state.landmarks[slot].p_world, slot);
    if (!linearized) {
      ++stats.rejected;
      continue;
    }
    const int offset_slot = state.offset_slot(observation.id);
    if (offset_slot >= 0) apply_offset(state, offset_slot, *linearized);
    // The newest observation's rows are the track's last four.
    const Eigen::Matrix4d added_noise =
        first_estimate_noise(state, slot, linearized->H_point.bottomRows<4>());
    if (track.size() == 1) {
      UpdaterHelper::whiten_inplace(
          *linearized,
          added_noise.isZero(0.0)
              ? whitening_
              : UpdaterHelper::whitening(independent_covariance_ + constant_covariance_ +
                                         persistent_covariance_ + added_noise));
    } else if (!condition_on_earlier(track, *linearized, added_noise)) {
      ++stats.rejected;
      continue;
    }
    const Eigen::MatrixXd identity = Eigen::MatrixXd::Identity(4, 4);
    if (StateHelper::mahalanobis_squared(state, linearized->H_state, linearized->residual,
                                         identity) > gate_4dof) {
      ++stats.rejected;
      continue;
    }
    state.landmarks[slot].last_observed_frame = frame;
    if (offset_slot >= 0) state.landmarks[offset_slot].last_observed_frame = frame;
    if (persistent_) state.landmarks[slot].used_observations = std::move(track);
    if (state.landmarks[slot].archived) {
      state.landmarks[slot].archived = false;  // seen again: active, with every correlation it kept
      ++stats.reactivated;
    }
    accepted_rows += static_cast<int>(linearized->residual.size());
    accepted.push_back(std::move(*linearized));
    ++stats.updated;
  }

  // 2. One stacked Kalman update for all accepted object observations (eq. 26-28).
  if (!accepted.empty()) {
    Eigen::MatrixXd H(accepted_rows, state.dimension());
    Eigen::VectorXd residual(accepted_rows);
    int row = 0;
    for (const LinearizedTrack& linearized : accepted) {
      const auto rows = linearized.residual.size();
      H.middleRows(row, rows) = linearized.H_state;
      residual.segment(row, rows) = linearized.residual;
      row += static_cast<int>(rows);
    }
    if (!StateHelper::update(state, H, residual, Eigen::MatrixXd::Identity(row, row))) {
      ++stats.update_failures;
    }
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
      const InitResult result = try_initialize(state, it->first, track, stats);
      if (result == InitResult::kInitialized) {
        ++stats.initialized;
        it = pending_.erase(it);
        continue;
      }
      ++(result == InitResult::kGated ? stats.init_gated : stats.init_failed);
    }
    ++it;
  }

  // 4. Bound the joint state.
  archive_stale(state, frame, stats);
  return stats;
}

ObjectUpdater::InitResult ObjectUpdater::try_initialize(State& state, LandmarkId id,
                                                        const std::vector<TrackObservation>& track,
                                                        ObjectUpdateStats& stats) {
  std::vector<Eigen::Isometry3d> poses;
  std::vector<Eigen::Vector4d> observations;
  for (const TrackObservation& observation : track) {
    const int slot = state.pose_slot(observation.frame);
    if (slot < 0) continue;
    poses.push_back(state.poses[slot].T_world_body);
    observations.push_back(UpdaterHelper::without_disparity_offset(state, camera_, observation.xy));
  }
  // 1. Stereo triangulation and refinement over the window's observations.
  const auto p_world = UpdaterHelper::triangulate(camera_, poses, observations);
  if (!p_world) return InitResult::kFailed;
  // 2. Rejection on reprojection error, cheirality and distance.
  const double rms = UpdaterHelper::rms_reprojection_error(camera_, poses, observations, *p_world) *
                     camera_.focal_length();
  if (!(rms <= options_.object_init_max_reprojection_error)) return InitResult::kFailed;
  const auto newest = UpdaterHelper::project(camera_, poses.back(), *p_world);
  if (!newest || newest->depth_left < options_.object_min_distance ||
      newest->depth_left > options_.object_max_distance) {
    return InitResult::kFailed;
  }
  // With detection offsets the new object's comes first, so that its rows (the new object's
  // and the others') carry it and the new object's cross-covariances include it; a refused
  // initialization takes it out again.
  const int existing_offset = state.offset_slot(id);
  const bool new_offset = has_offsets() && existing_offset < 0;
  const int offset_slot =
      new_offset ? add_offset(state, id, track.back().frame, stats) : existing_offset;
  const auto give_up = [&](InitResult result) {
    if (new_offset) {
      StateHelper::remove_landmarks(state, {offset_slot});
      --stats.offsets_added;
    }
    return result;
  };
  // 3. Linearize, whiten and split with QR (eq. 29): Q^T H_point = [R1; 0].
  auto linearized = UpdaterHelper::linearize(state, camera_, track, *p_world);
  if (!linearized) return give_up(InitResult::kFailed);
  if (offset_slot >= 0) apply_offset(state, offset_slot, *linearized);
  if (persistent_) {
    // The observations' errors are correlated: whitened by their joint covariance.
    const Eigen::LLT<Eigen::MatrixXd> factor(track_noise(track));
    if (factor.info() != Eigen::Success) return give_up(InitResult::kFailed);
    const auto lower = factor.matrixL();
    // Only the columns of the track's poses (and calibration) are not zero: whiten those.
    const std::vector<int> columns = StateHelper::nonzero_columns(linearized->H_state);
    Eigen::MatrixXd compact = linearized->H_state(Eigen::all, columns);
    lower.solveInPlace(compact);
    linearized->H_state(Eigen::all, columns) = compact;
    lower.solveInPlace(linearized->H_point);
    lower.solveInPlace(linearized->residual);
  } else {
    UpdaterHelper::whiten_inplace(*linearized, whitening_);
  }
  const Eigen::Index rows = linearized->residual.size();
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(linearized->H_point);
  const Eigen::MatrixXd Qt = qr.householderQ().transpose();
  // Qt mixes the rows; only the track's pose (and calibration) columns are not zero.
  const std::vector<int> state_columns = StateHelper::nonzero_columns(linearized->H_state);
  Eigen::MatrixXd H_state_rotated = Eigen::MatrixXd::Zero(rows, linearized->H_state.cols());
  H_state_rotated(Eigen::all, state_columns) = Qt * linearized->H_state(Eigen::all, state_columns);
  const Eigen::VectorXd residual_rotated = Qt * linearized->residual;
  const Eigen::Matrix3d R1 =
      qr.matrixQR().topLeftCorner<3, 3>().triangularView<Eigen::Upper>().toDenseMatrix();
  if (std::abs(R1.determinant()) < 1e-12) return give_up(InitResult::kFailed);

  // 4. The rows that do not involve the new object must agree with the state: chi-square test
  //    under their full innovation covariance (a wrong association or an outlier fails it).
  Eigen::MatrixXd H2;
  Eigen::VectorXd r2;
  if (rows > 3) {
    H2 = H_state_rotated.bottomRows(rows - 3);
    r2 = residual_rotated.tail(rows - 3);
    const auto dof = static_cast<int>(rows - 3);
    if (StateHelper::mahalanobis_squared(state, H2, r2, Eigen::MatrixXd::Identity(dof, dof)) >
        gate(dof)) {
      return give_up(InitResult::kGated);
    }
  }

  // 5. Too uncertain for a Gaussian yet (relative to its distance): wait for better views.
  if (options_.object_max_relative_sigma > 0.0) {
    const Eigen::MatrixXd H1 = H_state_rotated.topRows(3);
    const std::vector<int> columns = StateHelper::nonzero_columns(H1);
    const Eigen::Matrix3d R1_inverse = R1.inverse();
    const Eigen::Matrix3d covariance =
        R1_inverse *
        (H1(Eigen::all, columns) * state.covariance(columns, columns) *
             H1(Eigen::all, columns).transpose() +
         Eigen::Matrix3d::Identity()) *
        R1_inverse.transpose();
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(covariance, Eigen::EigenvaluesOnly);
    const double largest_sigma = std::sqrt(std::max(eigen.eigenvalues().maxCoeff(), 0.0));
    if (!(largest_sigma <= options_.object_max_relative_sigma * newest->depth_left)) {
      return give_up(InitResult::kFailed);
    }
  }

  // 6. Augment (eq. 30), then update with the rows that do not involve the new object.
  const Eigen::Vector3d p_new = *p_world + R1.inverse() * residual_rotated.head<3>();
  StateHelper::augment_landmark(state, id, p_new, *p_world, track.back().frame,
                                H_state_rotated.topRows(3), R1, Eigen::Matrix3d::Identity());
  if (persistent_) state.landmarks[state.landmark_slot(id)].used_observations = track;
  if (rows > 3) {
    Eigen::MatrixXd H2_full = Eigen::MatrixXd::Zero(rows - 3, state.dimension());
    H2_full.leftCols(H2.cols()) = H2;
    if (!StateHelper::update(state, H2_full, r2, Eigen::MatrixXd::Identity(rows - 3, rows - 3))) {
      ++stats.update_failures;
    }
  }

  // 7. An archived object rejoins: its old marginal and the fresh estimate are two estimates of
  //    one position with unknown correlation (both rest on this robot's trajectory), fused by
  //    covariance intersection into the new landmark's marginal. The rest of the state moves
  //    by the conditional (Proposition 2), but its covariance does not shrink: how the old
  //    marginal's errors correlate with the poses' is unknown, so what the object gained says
  //    nothing certain about them (docs/estimator.md, "Archiving").
  //    First the two must agree: their difference within the object gate (chi-square, 3 dof)
  //    under the sum of their covariances (errors that rest on one trajectory are correlated
  //    positively, so the sum is the wider bound). An old marginal beyond it is wrong (averaged
  //    with a wrong merge, or the object is another one) or the robot is, and fusing it would
  //    drag the whole state by the conditional: it is dropped, the fresh estimate stands, and
  //    the refusal is counted.
  if (const auto archived = state.archived.find(id); archived != state.archived.end()) {
    const int slot = state.landmark_slot(id);
    const int index = state.landmark_index(slot);
    const ObjectEstimate fresh{id, state.landmarks[slot].p_world,
                               state.covariance.block<3, 3>(index, index)};
    const Eigen::Vector3d difference = fresh.p_world - archived->second.p_world;
    const Eigen::LLT<Eigen::Matrix3d> sum(fresh.covariance + archived->second.covariance);
    const bool agrees =
        sum.info() == Eigen::Success && difference.dot(sum.solve(difference)) <= gate(3);
    if (!agrees) {
      ++stats.rejoins_refused;
    } else if (const auto fused = Consensus::covariance_intersection(fresh, archived->second)) {
      if (Consensus::replace_marginal_keeping_the_rest(state, slot, fused->p_world,
                                                       fused->covariance)) {
        ++stats.reactivated;
      } else {
        ++stats.update_failures;
      }
    }
    state.archived.erase(archived);
    state.archived_last_observed.erase(id);
    state.archived_local_covariance.erase(id);
  }
  return InitResult::kInitialized;
}

void ObjectUpdater::archive_stale(State& state, int frame, ObjectUpdateStats& stats) const {
  if (options_.object_archive_after_frames <= 0) return;
  // Stale detection offsets leave the state in either mode (a view seen again is a new view).
  std::vector<int> stale, stale_offsets;
  for (int slot = 0; slot < state.num_landmarks(); ++slot) {
    if (frame - state.landmarks[slot].last_observed_frame > options_.object_archive_after_frames) {
      (state.landmarks[slot].detection_offset ? stale_offsets : stale).push_back(slot);
    }
  }
  if (stale.empty() && stale_offsets.empty()) return;
  if (options_.object_archive_mode == "consider") {
    // Kept in the joint covariance as consider states (State, StateHelper::update).
    int archived = 0;
    for (int slot : stale) {
      archived += state.landmarks[slot].archived ? 0 : 1;
      state.landmarks[slot].archived = true;
    }
    stats.archived += archived;
    StateHelper::remove_landmarks(state, stale_offsets);
    return;
  }
  const NewestPoseConditioning conditioning(state);
  for (int slot : stale) {
    const auto& landmark = state.landmarks[slot];
    const int index = state.landmark_index(slot);
    const Eigen::Matrix3d marginal = state.covariance.block<3, 3>(index, index);
    state.archived[landmark.id] = {landmark.id, landmark.p_world, marginal};
    state.archived_last_observed[landmark.id] = landmark.last_observed_frame;
    state.archived_local_covariance.erase(landmark.id);
    if (const auto local = conditioning.of(index, 0.5 * (marginal + marginal.transpose()))) {
      state.archived_local_covariance[landmark.id] = *local;
    }
  }
  stats.archived += static_cast<int>(stale.size());
  stale.insert(stale.end(), stale_offsets.begin(), stale_offsets.end());
  StateHelper::remove_landmarks(state, stale);
}

}  // namespace concord
