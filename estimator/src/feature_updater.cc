#include "concord/estimator/feature_updater.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cassert>
#include <cmath>

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
  correlation_transposed_ = correlation.transpose();
  has_correlation_ = !correlation.isZero(0.0);
}

Eigen::Matrix4d FeatureUpdater::observation_whitening(const TrackObservation& observation) const {
  if (observation.sigma.isZero(0.0)) return whitening_;
  // Independent coordinates: the inverse standard deviations, in normalized units.
  const double fx = camera_.K(0, 0), fy = camera_.K(1, 1);
  const double left = observation.sigma(0), right = observation.sigma(1);
  return Eigen::Vector4d(fx / left, fy / left, fx / right, fy / right).asDiagonal();
}

namespace {

/// -1 / (sqrt(1 + s) (1 + sqrt(1 + s))) = ((1 + s)^(-1/2) - 1) / s, without the cancellation
/// at small s (-1/2 at s = 0).
double inverse_root_step(double s) {
  const double root = std::sqrt(1.0 + s);
  return -1.0 / (root * (1.0 + root));
}

/// Left-multiplies `rows` by (I + U U^T)^(-1/2) (U: 4n x 2). With U = Q diag(sqrt(s)) V^T (thin
/// SVD; U^T U = V diag(s) V^T) that is I + U V diag(inverse_root_step(s)) V^T U^T: O(n) instead
/// of factoring a 4n x 4n matrix. `U_middle` is U V diag(inverse_root_step(s)) V^T; `projected`
/// the caller's buffer.
template <typename Rows>
void apply_inverse_root(const Eigen::MatrixXd& U, const Eigen::MatrixXd& U_middle, Rows&& rows,
                        Eigen::Matrix<double, 2, Eigen::Dynamic>& projected) {
  projected.noalias() = U.transpose() * rows;
  rows.noalias() += U_middle * projected;
}

}  // namespace

void FeatureUpdater::whiten(LinearizedTrack& track,
                            const std::vector<TrackObservation>& observations) {
  const auto n = static_cast<Eigen::Index>(observations.size());
  assert(track.residual.size() == 4 * n);  // UpdaterHelper::linearize: 4 rows an observation
  // 1. Each observation's own noise (W_a): its four rows get the identity covariance.
  // 2. A random slope per track, common to both images: observation a moves by
  //    (k_a - k_mean) (c, d, c, d), (c, d) ~ N(0, sigma^2 I). In the rows whitened by 1. its
  //    covariance is U U^T, U's rows of observation a (k_a - k_mean) W_a C sigma, C = [I; I]:
  //    the rows' covariance is I + U U^T, whitened by its inverse square root (rank 2).
  const bool drift = options_.feature_drift_sigma > 0.0;
  double mean_frame = 0.0;
  for (const TrackObservation& observation : observations) mean_frame += observation.frame;
  mean_frame /= static_cast<double>(n);
  const double sigma = options_.feature_drift_sigma / camera_.focal_length();
  Eigen::Matrix<double, 4, 2> common;
  common << 1, 0, 0, 1, 1, 0, 0, 1;
  if (drift) drift_rows_.resize(4 * n, 2);
  for (Eigen::Index a = 0; a < n; ++a) {
    const Eigen::Matrix4d whitening = observation_whitening(observations[a]);
    track.H_state.middleRows<4>(4 * a) = (whitening * track.H_state.middleRows<4>(4 * a)).eval();
    track.H_point.middleRows<4>(4 * a) = (whitening * track.H_point.middleRows<4>(4 * a)).eval();
    track.residual.segment<4>(4 * a) = (whitening * track.residual.segment<4>(4 * a)).eval();
    if (drift) {
      drift_rows_.middleRows<4>(4 * a) =
          ((observations[a].frame - mean_frame) * sigma) * (whitening * common);
    }
  }
  if (!drift) return;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eigen(drift_rows_.transpose() * drift_rows_);
  const Eigen::Vector2d s = eigen.eigenvalues().cwiseMax(0.0);
  const Eigen::Matrix2d middle =
      eigen.eigenvectors() *
      Eigen::Vector2d(inverse_root_step(s(0)), inverse_root_step(s(1))).asDiagonal() *
      eigen.eigenvectors().transpose();
  drift_rows_middle_.noalias() = drift_rows_ * middle;
  apply_inverse_root(drift_rows_, drift_rows_middle_, track.residual, drift_projected_);
  apply_inverse_root(drift_rows_, drift_rows_middle_, track.H_state, drift_projected_);
  apply_inverse_root(drift_rows_, drift_rows_middle_, track.H_point, drift_projected_);
}

FeatureUpdateStats FeatureUpdater::process(State& state,
                                           const std::vector<StereoObservation>& features) {
  FeatureUpdateStats stats;
  const int frame = state.newest_pose().frame;
  const int oldest_frame = state.poses.front().frame;
  for (const StereoObservation& observation : features) {
    tracks_[observation.id].push_back(
        {frame, camera_.normalize(observation.uv), observation.sigma});
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
    // A drift model with the odometry correlation term would need that term whitened for the
    // drift too: the options refuse the two together.
    whiten(*linearized, track);
    Eigen::MatrixXd correlation_rows;  // S^T rows (rows x 6, newest pose columns), whitened
    Eigen::MatrixXd* extra = nullptr;
    if (has_correlation_) {
      correlation_rows = Eigen::MatrixXd::Zero(linearized->residual.size(), 6);
      if (linearized->newest_frame_row >= 0) {
        // Whitened like the newest observation's rows.
        correlation_rows.middleRows<4>(linearized->newest_frame_row) =
            observation_whitening(track.back()) * correlation_transposed_;
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
