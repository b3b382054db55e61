#include "concord/estimator/feature_updater.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cassert>

#include "concord/estimator/state_helper.h"

namespace concord {

FeatureUpdater::FeatureUpdater(const EstimatorOptions& options, const StereoCamera& camera)
    : options_(options),
      camera_(camera),
      whitening_(UpdaterHelper::whitening(
          UpdaterHelper::observation_covariance(options.feature_noise, camera))) {
  Eigen::Matrix<double, 6, 4> correlation;
  for (int row = 0; row < 6; ++row) {
    for (int col = 0; col < 4; ++col) {
      correlation(row, col) = options.feature_odometry_correlation[4 * row + col];
    }
  }
  correlation /= camera.focal_length();
  // Whitened like the observations: S^T rows are left-multiplied by the same matrix.
  correlation_transposed_ = whitening_ * correlation.transpose();
  has_correlation_ = !correlation.isZero(0.0);
  // The slope is common to both images: (u_left, v_left, u_right, v_right) move by (a, b, a, b).
  Eigen::Matrix4d common;
  common << 1, 0, 1, 0,  //
      0, 1, 0, 1,        //
      1, 0, 1, 0,        //
      0, 1, 0, 1;
  const double sigma = options.feature_drift_sigma / camera.focal_length();
  drift_covariance_ = whitening_ * (sigma * sigma * common) * whitening_.transpose();
}

namespace {

/// Whitens a track's rows (already whitened observation by observation) for a random slope per
/// track: their covariance is I + (k_a - k_mean)(k_b - k_mean) D between observations a and b.
/// `covariance` is the caller's buffer (factored in place).
void whiten_drift(LinearizedTrack& track, const std::vector<TrackObservation>& observations,
                  const Eigen::Matrix4d& drift, Eigen::MatrixXd& covariance) {
  const auto n = static_cast<Eigen::Index>(observations.size());
  assert(track.residual.size() == 4 * n);  // UpdaterHelper::linearize: 4 rows an observation
  double mean_frame = 0.0;
  for (const TrackObservation& observation : observations) mean_frame += observation.frame;
  mean_frame /= static_cast<double>(n);
  covariance.setIdentity(4 * n, 4 * n);
  for (Eigen::Index a = 0; a < n; ++a) {
    const double ta = observations[a].frame - mean_frame;
    for (Eigen::Index b = 0; b < n; ++b) {
      covariance.block<4, 4>(4 * a, 4 * b) += ta * (observations[b].frame - mean_frame) * drift;
    }
  }
  // Identity plus a positive semi-definite term: positive definite.
  const Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> llt(covariance);
  const auto lower = llt.matrixL();
  lower.solveInPlace(track.residual);
  lower.solveInPlace(track.H_state);
  lower.solveInPlace(track.H_point);
}

}  // namespace

FeatureUpdateStats FeatureUpdater::process(State& state,
                                           const std::vector<StereoObservation>& features) {
  FeatureUpdateStats stats;
  const int frame = state.newest_pose().frame;
  const int oldest_frame = state.poses.front().frame;
  for (const StereoObservation& observation : features) {
    tracks_[observation.id].push_back({frame, camera_.normalize(observation.uv)});
    ++stats.observations;
  }

  // 1. Select tracks that ended or fill the window (or their chunk, feature_max_observations);
  //    drop observations that left the window.
  const int chunk = options_.feature_max_observations > 0
                        ? std::min(options_.feature_max_observations, options_.window_size)
                        : options_.window_size;
  std::vector<LandmarkId> selected;
  for (auto it = tracks_.begin(); it != tracks_.end();) {
    auto& track = it->second;
    std::erase_if(track, [&](const TrackObservation& o) { return o.frame < oldest_frame; });
    const bool ended = track.empty() || track.back().frame != frame;
    const bool fills_chunk = static_cast<int>(track.size()) >= chunk;
    if (ended && static_cast<int>(track.size()) < options_.feature_min_observations) {
      it = tracks_.erase(it);
      continue;
    }
    if (ended || fills_chunk) selected.push_back(it->first);
    ++it;
  }
  if (selected.empty()) return stats;

  // 2. Triangulate, linearize, project onto the null space (eq. 24), gate.
  std::vector<LinearizedTrack> accepted;
  std::vector<Eigen::MatrixXd> accepted_correlations;
  Eigen::Index total_rows = 0;
  for (LandmarkId id : selected) {
    const auto& track = tracks_[id];
    std::vector<Eigen::Isometry3d> poses;
    std::vector<Eigen::Vector4d> observations;
    for (const TrackObservation& observation : track) {
      poses.push_back(state.poses[state.pose_slot(observation.frame)].T_world_body);
      observations.push_back(UpdaterHelper::without_disparity_offset(state, camera_, observation.xy));
    }
    const auto p_world = UpdaterHelper::triangulate(camera_, poses, observations);
    bool usable = p_world.has_value();
    if (usable) {
      const double rms =
          UpdaterHelper::rms_reprojection_error(camera_, poses, observations, *p_world) *
          camera_.focal_length();
      const auto newest = UpdaterHelper::project(camera_, poses.back(), *p_world);
      const bool fits = options_.feature_max_reprojection_error == 0.0 ||
                        rms <= options_.feature_max_reprojection_error;
      usable = fits && newest &&
               newest->depth_left >= options_.feature_min_distance &&
               newest->depth_left <= options_.feature_max_distance;
    }
    auto linearized =
        usable ? UpdaterHelper::linearize(state, camera_, track, *p_world) : std::nullopt;
    if (!linearized) {
      ++stats.tracks_rejected;
      continue;
    }
    UpdaterHelper::whiten_inplace(*linearized, whitening_);
    // A drift model with the odometry correlation term would need that term whitened too: the
    // options refuse the two together.
    if (options_.feature_drift_sigma > 0.0) {
      whiten_drift(*linearized, track, drift_covariance_, drift_rows_);
    }
    Eigen::MatrixXd correlation_rows;  // S^T rows (rows x 6, newest pose columns), whitened
    Eigen::MatrixXd* extra = nullptr;
    if (has_correlation_) {
      correlation_rows = Eigen::MatrixXd::Zero(linearized->residual.size(), 6);
      if (linearized->newest_frame_row >= 0) {
        correlation_rows.middleRows<4>(linearized->newest_frame_row) = correlation_transposed_;
      }
      extra = &correlation_rows;
    }
    UpdaterHelper::nullspace_project_inplace(linearized->H_state, linearized->H_point,
                                             linearized->residual, extra);
    const Eigen::Index rows = linearized->residual.size();
    const Eigen::MatrixXd noise = Eigen::MatrixXd::Identity(rows, rows);
    const double threshold = options_.feature_chi2_probability > 0.0
                                 ? UpdaterHelper::chi2_quantile(options_.feature_chi2_probability,
                                                                static_cast<int>(rows))
                                 : std::numeric_limits<double>::infinity();
    // The gate uses the innovation covariance of the update, correlation term included.
    Eigen::MatrixXd S_track;
    if (has_correlation_) {
      S_track = Eigen::MatrixXd::Zero(state.dimension(), rows);
      S_track.middleRows<6>(state.pose_index(state.num_poses() - 1)) = correlation_rows.transpose();
    }
    if (StateHelper::mahalanobis_squared(state, linearized->H_state, linearized->residual, noise,
                                         has_correlation_ ? &S_track : nullptr) > threshold) {
      ++stats.tracks_rejected;
      continue;
    }
    total_rows += rows;
    accepted.push_back(std::move(*linearized));
    if (has_correlation_) accepted_correlations.push_back(std::move(correlation_rows));
    ++stats.tracks_used;
  }

  // 3. Consume the used observations: ended tracks go, tracks that filled their chunk start afresh.
  for (LandmarkId id : selected) {
    auto it = tracks_.find(id);
    if (it->second.back().frame != frame) {
      tracks_.erase(it);
    } else {
      it->second.clear();
    }
  }
  std::erase_if(tracks_, [](const auto& entry) { return entry.second.empty(); });
  if (accepted.empty()) return stats;
  stats.rows = static_cast<int>(total_rows);

  // 4. Stack, compress when taller than the state, and update once (eq. 26-28).
  Eigen::MatrixXd H(total_rows, state.dimension());
  Eigen::VectorXd residual(total_rows);
  Eigen::MatrixXd correlation_rows;
  if (has_correlation_) correlation_rows.resize(total_rows, 6);
  Eigen::Index row = 0;
  for (std::size_t i = 0; i < accepted.size(); ++i) {
    const Eigen::Index rows = accepted[i].residual.size();
    H.middleRows(row, rows) = accepted[i].H_state;
    residual.segment(row, rows) = accepted[i].residual;
    if (has_correlation_) correlation_rows.middleRows(row, rows) = accepted_correlations[i];
    row += rows;
  }
  UpdaterHelper::measurement_compress_inplace(H, residual,
                                              has_correlation_ ? &correlation_rows : nullptr);
  const Eigen::Index rows = residual.size();
  const Eigen::MatrixXd noise = Eigen::MatrixXd::Identity(rows, rows);
  bool updated = false;
  if (has_correlation_) {
    // S (n x m): non-zero only in the newest pose's rows, where the odometry noise enters.
    Eigen::MatrixXd S = Eigen::MatrixXd::Zero(state.dimension(), rows);
    S.middleRows<6>(state.pose_index(state.num_poses() - 1)) = correlation_rows.transpose();
    updated = StateHelper::update(state, H, residual, noise, &S);
  } else {
    updated = StateHelper::update(state, H, residual, noise);
  }
  if (!updated) ++stats.update_failures;
  return stats;
}

}  // namespace concord
