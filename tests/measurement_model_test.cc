// Every measurement and motion Jacobian against finite differences, the null-space projection,
// measurement compression, the chi-square quantiles and triangulation.
#include <gtest/gtest.h>

#include <random>
#include <tuple>

#include "concord/estimator/feature_updater.h"
#include "concord/estimator/lie.h"
#include "concord/estimator/propagator.h"
#include "concord/estimator/state_helper.h"
#include "concord/estimator/updater_helper.h"
#include "test_support.h"

namespace concord {
namespace {

using testing::kitti_like_camera;

Eigen::Isometry3d some_pose() {
  return lie::se3_exp((lie::Vector6d() << 3.0, -1.0, 0.5, 0.05, -0.02, 0.3).finished());
}

TEST(StereoProjection, PoseJacobianMatchesFiniteDifferences) {
  const StereoCamera camera = kitti_like_camera();
  const Eigen::Isometry3d T = some_pose();
  const Eigen::Vector3d p_world = T * Eigen::Vector3d(12.0, 1.5, 0.7);
  const auto projection = UpdaterHelper::project(camera, T, p_world);
  ASSERT_TRUE(projection);
  const double h = 1e-6;
  for (int i = 0; i < 6; ++i) {
    const lie::Vector6d d = h * lie::Vector6d::Unit(i);
    // The state's left perturbation: T = exp(eps^) T_hat.
    const auto plus = UpdaterHelper::project(camera, lie::se3_exp(d) * T, p_world);
    const auto minus = UpdaterHelper::project(camera, lie::se3_exp(-d) * T, p_world);
    const Eigen::Vector4d numeric = (plus->xy - minus->xy) / (2 * h);
    EXPECT_TRUE(numeric.isApprox(projection->jacobian_pose.col(i), 1e-6))
        << "column " << i << ": numeric " << numeric.transpose() << " analytic "
        << projection->jacobian_pose.col(i).transpose();
  }
}

TEST(StereoProjection, AChangeOfWorldFrameIsUnobservable) {
  // Moving the world frame by exp(xi^) moves every pose to exp(xi^) T and every point to
  // exp(xi^) p: to first order the pose error is xi itself (left perturbation) and the point
  // error rho + phi x p. The observation does not change: H_pose xi + H_point (rho + phi x p)
  // = 0 for every xi, whatever the pose and point, when the pose Jacobian is evaluated with the
  // same point (first-estimate Jacobians keep this across a landmark's observations).
  const StereoCamera camera = kitti_like_camera();
  std::mt19937 random(5);
  for (int trial = 0; trial < 5; ++trial) {
    const Eigen::Isometry3d T =
        lie::se3_exp(testing::random_vector(6, random, 0.5)) * some_pose();
    const Eigen::Vector3d p_world = T * Eigen::Vector3d(10.0 + trial, 1.0, -0.5);
    const auto projection = UpdaterHelper::project(camera, T, p_world);
    ASSERT_TRUE(projection);
    const Eigen::Vector3d p_linearization = p_world + testing::random_vector(3, random, 0.3);
    const Eigen::Matrix<double, 4, 6> H_pose =
        UpdaterHelper::pose_jacobian(projection->jacobian_point, p_linearization);
    Eigen::Matrix<double, 3, 6> point_motion;
    point_motion.leftCols<3>() = Eigen::Matrix3d::Identity();
    point_motion.rightCols<3>() = -lie::skew(p_linearization);
    const Eigen::Matrix<double, 4, 6> total = H_pose + projection->jacobian_point * point_motion;
    EXPECT_LT(total.norm(), 1e-9 * H_pose.norm()) << total;
  }
}

TEST(StereoProjection, PointJacobianMatchesFiniteDifferences) {
  const StereoCamera camera = kitti_like_camera();
  const Eigen::Isometry3d T = some_pose();
  const Eigen::Vector3d p_world = T * Eigen::Vector3d(8.0, -2.0, 1.0);
  const auto projection = UpdaterHelper::project(camera, T, p_world);
  ASSERT_TRUE(projection);
  const double h = 1e-6;
  for (int i = 0; i < 3; ++i) {
    const Eigen::Vector3d d = h * Eigen::Vector3d::Unit(i);
    const Eigen::Vector4d numeric = (UpdaterHelper::project(camera, T, p_world + d)->xy -
                                     UpdaterHelper::project(camera, T, p_world - d)->xy) /
                                    (2 * h);
    EXPECT_TRUE(numeric.isApprox(projection->jacobian_point.col(i), 1e-6));
  }
}

TEST(StereoProjection, MatchesPinholeAndRejectsPointsBehind) {
  const StereoCamera camera = kitti_like_camera();
  // A point 10 m ahead, 1 m left of the body: camera x = -1, z = 10.
  const auto projection =
      UpdaterHelper::project(camera, Eigen::Isometry3d::Identity(), Eigen::Vector3d(10, 1, 0));
  ASSERT_TRUE(projection);
  EXPECT_NEAR(projection->xy(0), -0.1, 1e-12);
  EXPECT_NEAR(projection->xy(2), (-1.0 - 0.5323) / 10.0, 1e-12);
  EXPECT_NEAR(projection->depth_left, 10.0, 1e-12);
  EXPECT_FALSE(
      UpdaterHelper::project(camera, Eigen::Isometry3d::Identity(), Eigen::Vector3d(-10, 1, 0)));
}

TEST(StereoCamera, NormalizeInvertsDenormalize) {
  const StereoCamera camera = kitti_like_camera();
  const Eigen::Vector4d uv(700.0, 200.0, 650.0, 200.0);
  EXPECT_TRUE(camera.denormalize(camera.normalize(uv)).isApprox(uv, 1e-12));
}

TEST(Propagation, AdjointMapsThePerturbation) {
  // T_old exp(eps) dT == (T_old dT) exp(Ad(dT^-1) eps): the Jacobian J_t of eq. (23).
  const Eigen::Isometry3d T_old = some_pose();
  const Eigen::Isometry3d dT =
      lie::se3_exp((lie::Vector6d() << 0.7, 0.01, 0.0, 0.0, 0.01, 0.05).finished());
  const lie::Vector6d eps = (lie::Vector6d() << 1e-4, -2e-4, 3e-4, 1e-4, 2e-4, -1e-4).finished();
  const Eigen::Isometry3d lhs = T_old * lie::se3_exp(eps) * dT;
  const Eigen::Isometry3d rhs = T_old * dT * lie::se3_exp(lie::adjoint(dT.inverse()) * eps);
  EXPECT_TRUE(lhs.matrix().isApprox(rhs.matrix(), 1e-12));
}

TEST(Propagation, CovarianceMatchesTheLinearizedModel) {
  std::mt19937 random(7);
  State state = testing::random_state(3, 2, random);
  const State before = state;
  EstimatorOptions options;
  options.window_size = 3;
  options.odometry_translation_sigma = 0.05;
  options.odometry_rotation_sigma = 0.01;
  const Propagator propagator(options);
  const Eigen::Isometry3d dT =
      lie::se3_exp((lie::Vector6d() << 0.7, 0.01, 0.0, 0.0, 0.01, 0.05).finished());
  propagator.propagate(state, dT, 3);
  // Full window: the oldest pose is dropped, the new one appended after the poses.
  ASSERT_EQ(state.num_poses(), 3);
  EXPECT_EQ(state.poses.front().frame, 1);
  EXPECT_EQ(state.poses.back().frame, 3);
  EXPECT_TRUE(state.poses.back().T_world_body.matrix().isApprox(
      (before.poses.back().T_world_body * dT).matrix(), 1e-12));
  // Dense reference: F with rows [drop pose 0 | keep 1, 2 | new = pose 2 | landmarks]: with
  // left perturbations the new pose's error is the newest one's, and the odometry noise (a
  // right perturbation of dT) enters through Ad(T_new).
  const int n = before.dimension();
  Eigen::MatrixXd F = Eigen::MatrixXd::Zero(n, n);
  F.block<12, 12>(0, 6).setIdentity();
  F.block<6, 6>(12, 12).setIdentity();
  F.bottomRightCorner(6, 6).setIdentity();
  const lie::Matrix6d adjoint_new = lie::adjoint(state.poses.back().T_world_body);
  Eigen::MatrixXd Q = Eigen::MatrixXd::Zero(n, n);
  Q.block<6, 6>(12, 12) = adjoint_new * propagator.odometry_noise() * adjoint_new.transpose();
  const Eigen::MatrixXd expected = F * before.covariance * F.transpose() + Q;
  EXPECT_TRUE(state.covariance.isApprox(expected, 1e-12));
}

TEST(NullspaceProjection, RemovesTheFeatureError) {
  std::mt19937 random(11);
  const int rows = 12;
  Eigen::MatrixXd H_state = Eigen::MatrixXd::Random(rows, 18);
  Eigen::MatrixXd H_point = Eigen::MatrixXd::Random(rows, 3);
  const Eigen::VectorXd residual = testing::random_vector(rows, random);
  const Eigen::Vector3d point_error(0.3, -1.2, 0.8);
  // The same system with the residual shifted by H_point * p~ projects to the same result.
  Eigen::MatrixXd H1 = H_state, P1 = H_point, H2 = H_state, P2 = H_point;
  Eigen::VectorXd r1 = residual, r2 = residual + H_point * point_error;
  UpdaterHelper::nullspace_project_inplace(H1, P1, r1);
  UpdaterHelper::nullspace_project_inplace(H2, P2, r2);
  EXPECT_EQ(r1.size(), rows - 3);
  EXPECT_TRUE(r1.isApprox(r2, 1e-12));
  // The result is N^T (H_state, r) for an orthonormal basis N of the left null space of H_point
  // (N^T H_point = 0, N^T N = I): then N N^T is the projector I - H_p (H_p^T H_p)^-1 H_p^T, so
  // the projected system keeps exactly the information outside the point's directions.
  const Eigen::MatrixXd projector =
      Eigen::MatrixXd::Identity(rows, rows) -
      H_point * (H_point.transpose() * H_point).inverse() * H_point.transpose();
  EXPECT_TRUE((H1.transpose() * H1).isApprox(H_state.transpose() * projector * H_state, 1e-9));
  EXPECT_TRUE((H1.transpose() * r1).isApprox(H_state.transpose() * projector * residual, 1e-9));
  EXPECT_NEAR(r1.squaredNorm(), residual.dot(projector * residual), 1e-9);
  EXPECT_GT(r1.norm(), 0.1);
}

TEST(MeasurementCompression, PreservesTheInformation) {
  std::mt19937 random(12);
  // 40 rows touching 6 of 20 columns.
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(40, 20);
  H.middleCols(4, 6) = Eigen::MatrixXd::Random(40, 6);
  Eigen::VectorXd r = testing::random_vector(40, random);
  const Eigen::MatrixXd information = H.transpose() * H;
  const Eigen::VectorXd information_vector = H.transpose() * r;
  UpdaterHelper::measurement_compress_inplace(H, r);
  EXPECT_EQ(H.rows(), 6);
  EXPECT_TRUE((H.transpose() * H).isApprox(information, 1e-10));
  EXPECT_TRUE((H.transpose() * r).isApprox(information_vector, 1e-10));
}

TEST(ChiSquare, QuantilesMatchTables) {
  // Published table values (5 significant digits).
  EXPECT_NEAR(UpdaterHelper::chi2_quantile(0.95, 1), 3.8415, 1e-4);
  EXPECT_NEAR(UpdaterHelper::chi2_quantile(0.95, 2), 5.9915, 1e-4);
  EXPECT_NEAR(UpdaterHelper::chi2_quantile(0.95, 4), 9.4877, 1e-4);
  EXPECT_NEAR(UpdaterHelper::chi2_quantile(0.95, 10), 18.307, 1e-3);
  EXPECT_NEAR(UpdaterHelper::chi2_quantile(0.95, 100), 124.342, 1e-3);
  EXPECT_NEAR(UpdaterHelper::chi2_quantile(0.99, 3), 11.345, 1e-3);
  EXPECT_NEAR(UpdaterHelper::chi2_quantile(0.05, 5), 1.1455, 1e-4);
}

TEST(ChiSquare, RepeatedQuestionsGetTheTableAnswersWhateverCameBefore) {
  // The quantiles are kept between calls (a few, per thread): more distinct questions than it
  // keeps, asked twice over in two orders, each time the table's answer.
  const std::vector<std::tuple<double, int, double>> table{
      {0.95, 1, 3.8415},  {0.95, 2, 5.9915},   {0.95, 3, 7.8147}, {0.95, 4, 9.4877},
      {0.95, 10, 18.307}, {0.99, 3, 11.345},   {0.99, 1, 6.6349}, {0.999, 3, 16.266},
      {0.05, 5, 1.1455},  {0.9999, 1, 15.137}, {0.5, 2, 1.3863}};
  for (int pass = 0; pass < 2; ++pass) {
    for (std::size_t k = 0; k < table.size(); ++k) {
      const auto& [probability, dof, expected] = table[pass == 0 ? k : table.size() - 1 - k];
      EXPECT_NEAR(UpdaterHelper::chi2_quantile(probability, dof), expected, 1e-3 * expected)
          << probability << " " << dof;
      EXPECT_NEAR(UpdaterHelper::chi2_quantile(probability, dof), expected, 1e-3 * expected)
          << probability << " " << dof << " (again)";
    }
  }
}

TEST(Triangulation, RecoversAPointFromNoiselessStereo) {
  const StereoCamera camera = kitti_like_camera();
  const Eigen::Vector3d p_world(15.0, 2.0, 0.5);
  std::vector<Eigen::Isometry3d> poses;
  std::vector<Eigen::Vector4d> observations;
  for (int k = 0; k < 3; ++k) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.translation() = Eigen::Vector3d(0.8 * k, 0.0, 0.0);
    poses.push_back(T);
    observations.push_back(UpdaterHelper::project(camera, T, p_world)->xy);
  }
  const auto estimate = UpdaterHelper::triangulate(camera, poses, observations);
  ASSERT_TRUE(estimate);
  EXPECT_LT((*estimate - p_world).norm(), 1e-8);
  EXPECT_LT(UpdaterHelper::rms_reprojection_error(camera, poses, observations, *estimate), 1e-10);
}

/// The frames at which one track, observed without noise in every frame from frame 0 on, enters
/// a feature update (FeatureUpdateStats::tracks_used) over `frames` frames.
std::vector<int> frames_a_track_is_used(const EstimatorOptions& options, int frames) {
  const StereoCamera camera = kitti_like_camera();
  FeatureUpdater updater(options, camera);
  const Eigen::Vector3d p_world(30.0, 1.5, 0.5);
  std::vector<int> used;
  for (int frame = 0; frame < frames; ++frame) {
    State state;  // poses 0..frame on a straight line, a small independent covariance
    for (int k = 0; k <= frame; ++k) {
      Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
      pose.translation() = Eigen::Vector3d(0.2 * k, 0.0, 0.0);
      state.poses.push_back({k, pose});
    }
    state.covariance = 1e-6 * Eigen::MatrixXd::Identity(state.dimension(), state.dimension());
    const auto projection = UpdaterHelper::project(camera, state.newest_pose().T_world_body, p_world);
    if (!projection) {
      ADD_FAILURE() << "the point is not in view at frame " << frame;
      return used;
    }
    StereoObservation observation;
    observation.id = 7;
    observation.uv = camera.denormalize(projection->xy);
    const FeatureUpdateStats stats = updater.process(state, {observation});
    EXPECT_EQ(stats.tracks_rejected, 0) << frame;
    if (stats.tracks_used > 0) used.push_back(frame);
  }
  return used;
}

TEST(FeatureUpdate, ATrackIsUsedInChunksOfFeatureMaxObservations) {
  EstimatorOptions options;
  options.window_size = 20;
  options.feature_min_observations = 3;
  options.feature_chi2_probability = 0.0;  // no gate: only the chunking is under test
  // Default: a track still in view is used once it fills the window, then starts afresh.
  EXPECT_EQ(frames_a_track_is_used(options, 45), (std::vector<int>{19, 39}));
  options.feature_max_observations = 4;
  EXPECT_EQ(frames_a_track_is_used(options, 12), (std::vector<int>{3, 7, 11}));
  // A chunk longer than the window is the window.
  options.feature_max_observations = 30;
  EXPECT_EQ(frames_a_track_is_used(options, 45), (std::vector<int>{19, 39}));
  // Validation: 0 or at least feature_min_observations.
  options.feature_max_observations = 2;
  ASSERT_EQ(options.validate().size(), 1u);
  EXPECT_NE(options.validate().front().find("feature_max_observations"), std::string::npos);
  options.feature_max_observations = -1;
  EXPECT_EQ(options.validate().size(), 1u);
  options.feature_max_observations = 0;
  EXPECT_TRUE(options.validate().empty());
}

/// One track of 8 observations whose rows drift by `drift_px` a frame (both images), fed to a
/// FeatureUpdater with `options`: the stats of the update at its eighth frame.
FeatureUpdateStats drifting_track_update(const EstimatorOptions& options, double drift_px) {
  const StereoCamera camera = kitti_like_camera();
  FeatureUpdater updater(options, camera);
  const Eigen::Vector3d p_world(30.0, 1.5, 0.5);
  FeatureUpdateStats last;
  for (int frame = 0; frame < 8; ++frame) {
    State state;
    for (int k = 0; k <= frame; ++k) {
      Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
      pose.translation() = Eigen::Vector3d(0.2 * k, 0.0, 0.0);
      state.poses.push_back({k, pose});
    }
    state.covariance = 1e-8 * Eigen::MatrixXd::Identity(state.dimension(), state.dimension());
    const auto projection =
        UpdaterHelper::project(camera, state.newest_pose().T_world_body, p_world);
    EXPECT_TRUE(projection);
    if (!projection) return last;
    StereoObservation observation;
    observation.id = 7;
    observation.uv = camera.denormalize(projection->xy);
    observation.uv[1] += drift_px * frame;
    observation.uv[3] += drift_px * frame;
    last = updater.process(state, {observation});
  }
  return last;
}

TEST(FeatureUpdate, ADriftModelTakesATrackThatDriftsForWhatItIs) {
  EstimatorOptions options;
  options.feature_noise = StereoNoise::isotropic(0.1);
  options.feature_max_observations = 8;  // the track is used at its eighth frame
  // A track whose rows drift by 0.3 px a frame (2.1 px over its frames) is no point seen with
  // 0.1 px of white noise: the gate refuses it.
  const FeatureUpdateStats white = drifting_track_update(options, 0.3);
  EXPECT_EQ(white.tracks_used, 0);
  EXPECT_EQ(white.tracks_rejected, 1);
  // With a random slope of 0.3 px a frame in the model the same track is an ordinary one.
  options.feature_drift_sigma = 0.3;
  const FeatureUpdateStats modelled = drifting_track_update(options, 0.3);
  EXPECT_EQ(modelled.tracks_used, 1);
  EXPECT_EQ(modelled.tracks_rejected, 0);
  // And a track without drift is still used.
  EXPECT_EQ(drifting_track_update(options, 0.0).tracks_used, 1);
  // Validation: finite and >= 0; not with the odometry correlation term.
  EXPECT_TRUE(options.validate().empty());
  options.feature_drift_sigma = -0.1;
  ASSERT_EQ(options.validate().size(), 1u);
  EXPECT_NE(options.validate().front().find("feature_drift_sigma"), std::string::npos);
  options.feature_drift_sigma = 0.3;
  options.feature_odometry_correlation[0] = 0.01;
  ASSERT_EQ(options.validate().size(), 1u);
  EXPECT_NE(options.validate().front().find("feature_odometry_correlation"), std::string::npos);
}

/// A window of `n` poses 0.2 m apart along x with a small prior covariance, and one track of a
/// point seen from each, its observations moved by `offsets` (pixels, one a frame) and given
/// `sigmas` (pixels; zero: the configured noise).
struct OneTrack {
  State state;
  std::vector<StereoObservation> observations;
};
OneTrack one_track(int n, const std::vector<Eigen::Vector4d>& offsets,
                   const std::vector<Eigen::Vector2d>& sigmas) {
  const StereoCamera camera = kitti_like_camera();
  const Eigen::Vector3d p_world(30.0, 1.5, 0.5);
  OneTrack out;
  for (int k = 0; k < n; ++k) {
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.translation() = Eigen::Vector3d(0.2 * k, 0.0, 0.0);
    out.state.poses.push_back({k, pose});
    const auto projection = UpdaterHelper::project(camera, pose, p_world);
    StereoObservation observation;
    observation.id = 7;
    observation.uv = camera.denormalize(projection->xy) + offsets[k];
    observation.sigma = sigmas[k];
    out.observations.push_back(observation);
  }
  std::mt19937 random(3);
  std::normal_distribution<double> normal;
  const int dimension = out.state.dimension();
  Eigen::MatrixXd A(dimension, dimension);
  for (int i = 0; i < dimension; ++i) {
    for (int j = 0; j < dimension; ++j) A(i, j) = normal(random);
  }
  out.state.covariance =
      1e-8 * (A * A.transpose() / dimension + Eigen::MatrixXd::Identity(dimension, dimension));
  return out;
}

/// The FeatureUpdater's update of `track` at its last frame (the window's poses all in the state
/// from the start, so the update sees the track whole): the state after it, and the stats.
std::pair<State, FeatureUpdateStats> update_with(const EstimatorOptions& options, OneTrack track) {
  FeatureUpdater updater(options, kitti_like_camera());
  State state = track.state;
  FeatureUpdateStats stats;
  const auto poses = state.poses;
  for (std::size_t k = 0; k < poses.size(); ++k) {
    // The updater reads the newest pose's frame: the window grows as frames come.
    state.poses.assign(poses.begin(), poses.begin() + static_cast<std::ptrdiff_t>(k + 1));
    State current = track.state;
    current.poses = state.poses;
    const int dimension = current.dimension();
    current.covariance = track.state.covariance.topLeftCorner(dimension, dimension);
    stats = updater.process(current, {track.observations[k]});
    state = current;
  }
  return {state, stats};
}

TEST(FeatureUpdate, AnObservationsOwnNoiseOfTheConfiguredSizeChangesNothing) {
  EstimatorOptions options;
  options.feature_noise = StereoNoise::isotropic(0.2);
  options.feature_drift_sigma = 0.05;
  options.feature_max_observations = 6;
  std::vector<Eigen::Vector4d> offsets(6, Eigen::Vector4d(0.1, -0.1, 0.05, -0.1));
  const auto [configured, configured_stats] =
      update_with(options, one_track(6, offsets, std::vector<Eigen::Vector2d>(6, {0.0, 0.0})));
  const auto [own, own_stats] =
      update_with(options, one_track(6, offsets, std::vector<Eigen::Vector2d>(6, {0.2, 0.2})));
  ASSERT_EQ(configured_stats.tracks_used, 1);
  ASSERT_EQ(own_stats.tracks_used, 1);
  EXPECT_LT((configured.covariance - own.covariance).cwiseAbs().maxCoeff(), 1e-15);
  // And the update did something: the covariance shrank.
  EXPECT_LT(own.covariance.trace(),
            one_track(6, offsets, {6, {0.0, 0.0}}).state.covariance.trace());
}

TEST(FeatureUpdate, ADriftModelWithOwnNoiseMatchesTheDenseWhitening) {
  // The updater whitens a track's rows for each observation's own noise, then for the slope
  // (rank 2) with the inverse square root of I + U U^T. Against the dense way: the rows' whole
  // covariance (own noise plus the slope's, 4n x 4n) factored and solved.
  const int n = 7;
  EstimatorOptions options;
  options.feature_noise = StereoNoise::isotropic(0.3);
  options.feature_drift_sigma = 0.08;
  options.feature_max_observations = n;
  options.feature_chi2_probability = 0.0;  // no gate: the update itself is compared
  std::vector<Eigen::Vector4d> offsets;
  std::vector<Eigen::Vector2d> sigmas;
  for (int k = 0; k < n; ++k) {
    offsets.emplace_back(0.07 * k, -0.05 * k + 0.1 * (k % 2), 0.07 * k - 0.2, -0.05 * k);
    sigmas.emplace_back(0.1 + 0.05 * k, 0.25 + 0.03 * (k % 3));
  }
  const OneTrack track = one_track(n, offsets, sigmas);
  const auto [updated, stats] = update_with(options, track);
  ASSERT_EQ(stats.tracks_used, 1);

  const StereoCamera camera = kitti_like_camera();
  State dense = track.state;
  std::vector<TrackObservation> observations;
  std::vector<Eigen::Isometry3d> poses;
  std::vector<Eigen::Vector4d> xy;
  for (int k = 0; k < n; ++k) {
    observations.push_back({k, camera.normalize(track.observations[k].uv), sigmas[k]});
    poses.push_back(dense.poses[k].T_world_body);
    xy.push_back(observations.back().xy);
  }
  const auto point = UpdaterHelper::triangulate(camera, poses, xy);
  ASSERT_TRUE(point);
  auto linearized = UpdaterHelper::linearize(dense, camera, observations, *point);
  ASSERT_TRUE(linearized);
  const double fx = camera.K(0, 0), fy = camera.K(1, 1);
  const double slope = options.feature_drift_sigma / camera.focal_length();
  Eigen::MatrixXd covariance = Eigen::MatrixXd::Zero(4 * n, 4 * n);
  Eigen::Matrix4d common;
  common << 1, 0, 1, 0, 0, 1, 0, 1, 1, 0, 1, 0, 0, 1, 0, 1;
  const double mean_frame = (n - 1) / 2.0;
  for (int a = 0; a < n; ++a) {
    const double l = sigmas[a](0), r = sigmas[a](1);
    covariance.block<4, 4>(4 * a, 4 * a) =
        Eigen::Vector4d(l * l / (fx * fx), l * l / (fy * fy), r * r / (fx * fx), r * r / (fy * fy))
            .asDiagonal();
    for (int b = 0; b < n; ++b) {
      covariance.block<4, 4>(4 * a, 4 * b) +=
          (a - mean_frame) * (b - mean_frame) * slope * slope * common;
    }
  }
  const Eigen::LLT<Eigen::MatrixXd> llt(covariance);
  ASSERT_EQ(llt.info(), Eigen::Success);
  const Eigen::MatrixXd lower = llt.matrixL();
  linearized->residual = lower.triangularView<Eigen::Lower>().solve(linearized->residual);
  linearized->H_state = lower.triangularView<Eigen::Lower>().solve(linearized->H_state);
  linearized->H_point = lower.triangularView<Eigen::Lower>().solve(linearized->H_point);
  UpdaterHelper::nullspace_project_inplace(linearized->H_state, linearized->H_point,
                                           linearized->residual);
  const Eigen::Index rows = linearized->residual.size();
  ASSERT_TRUE(StateHelper::update(dense, linearized->H_state, linearized->residual,
                                  Eigen::MatrixXd::Identity(rows, rows)));
  EXPECT_LT((updated.covariance - dense.covariance).cwiseAbs().maxCoeff(),
            1e-9 * dense.covariance.cwiseAbs().maxCoeff());
  for (int k = 0; k < n; ++k) {
    EXPECT_LT((updated.poses[k].T_world_body.matrix() - dense.poses[k].T_world_body.matrix())
                  .cwiseAbs()
                  .maxCoeff(),
              1e-9);
  }
  // The track moved the poses (the comparison is not of two untouched states).
  EXPECT_GT((dense.poses[n - 1].T_world_body.translation() -
             track.state.poses[n - 1].T_world_body.translation())
                .norm(),
            1e-6);
}

TEST(FeatureUpdate, AnObservationWithALargeOwnNoiseWeighsLittle) {
  // One observation 3 px off: under the configured 0.1 px the gate refuses the track; given its
  // own noise of 3 px, the track is used, and that observation moves the estimate a tenth as
  // much as it does under the configured noise with the gate off.
  EstimatorOptions options;
  options.feature_noise = StereoNoise::isotropic(0.1);
  options.feature_max_observations = 6;
  std::vector<Eigen::Vector4d> offsets(6, Eigen::Vector4d::Zero());
  const std::vector<Eigen::Vector4d> clean_offsets = offsets;
  offsets[3] = Eigen::Vector4d(3.0, -3.0, 3.0, -3.0);
  std::vector<Eigen::Vector2d> configured(6, Eigen::Vector2d::Zero());
  EXPECT_EQ(update_with(options, one_track(6, offsets, configured)).second.tracks_rejected, 1);
  std::vector<Eigen::Vector2d> own = configured;
  own[3] = Eigen::Vector2d(3.0, 3.0);
  const auto [state, stats] = update_with(options, one_track(6, offsets, own));
  EXPECT_EQ(stats.tracks_used, 1);
  const auto shift = [&](const std::vector<Eigen::Vector2d>& sigmas, const EstimatorOptions& o) {
    const State with = update_with(o, one_track(6, offsets, sigmas)).first;
    const State without = update_with(o, one_track(6, clean_offsets, sigmas)).first;
    double largest = 0.0;
    for (int k = 0; k < 6; ++k) {
      largest = std::max(largest, (with.poses[k].T_world_body.translation() -
                                   without.poses[k].T_world_body.translation())
                                      .norm());
    }
    return largest;
  };
  EstimatorOptions ungated = options;
  ungated.feature_chi2_probability = 0.0;
  const double configured_shift = shift(configured, ungated);
  EXPECT_GT(configured_shift, 0.0);
  EXPECT_LT(shift(own, options), 0.1 * configured_shift);
}

TEST(KalmanUpdate, CorrelatedNoiseMatchesGaussianConditioning) {
  // x ~ N(0, P), z = H x + v with Cov(x, v) = S: the posterior is the Gaussian conditional
  // of the joint (x, z), Cov(x, z) = P H^T + S, Cov(z) = H P H^T + V + H S + S^T H^T.
  std::mt19937 random(13);
  State state = testing::random_state(2, 1, random);
  const int n = state.dimension();
  const int m = 4;
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(m, n);
  H.middleCols(6, 6) = Eigen::MatrixXd::Random(m, 6);
  H.rightCols(3) = Eigen::MatrixXd::Random(m, 3);
  const Eigen::MatrixXd V = testing::random_spd(m, random, 0.5, 1.0);
  Eigen::MatrixXd S = Eigen::MatrixXd::Zero(n, m);
  S.middleRows(6, 6) = 0.05 * Eigen::MatrixXd::Random(6, m);
  const Eigen::VectorXd r = testing::random_vector(m, random);
  const Eigen::MatrixXd P = state.covariance;
  const Eigen::MatrixXd cross = P * H.transpose() + S;
  const Eigen::MatrixXd innovation =
      H * P * H.transpose() + V + H * S + S.transpose() * H.transpose();
  const Eigen::MatrixXd expected_covariance = P - cross * innovation.inverse() * cross.transpose();
  const Eigen::VectorXd expected_correction = cross * innovation.inverse() * r;

  const State before = state;
  ASSERT_TRUE(StateHelper::update(state, H, r, V, &S));
  EXPECT_TRUE(state.covariance.isApprox(expected_covariance, 1e-10));
  EXPECT_TRUE(state.landmarks[0].p_world.isApprox(
      before.landmarks[0].p_world + expected_correction.tail<3>(), 1e-10));
  const Eigen::Isometry3d expected_pose =
      lie::se3_exp(expected_correction.segment<6>(6)) * before.poses[1].T_world_body;
  EXPECT_TRUE(state.poses[1].T_world_body.matrix().isApprox(expected_pose.matrix(), 1e-10));
}

TEST(KalmanUpdate, ArchivedObjectsAreSchmidtConsiderStates) {
  // Two poses and three objects, the middle one archived (a consider state). The update must be
  // the Joseph form with the archived rows of the gain zeroed, K_s = E P H^T S^-1:
  //   P' = (I - K_s H) P (I - K_s H)^T + K_s V K_s^T,
  // which leaves the archived object's mean and covariance as they were and updates its
  // cross-covariances with the rest; with every object active it is the plain update.
  std::mt19937 random(21);
  State state = testing::random_state(2, 3, random);
  state.landmarks[1].archived = true;
  const int n = state.dimension();
  const int held = state.landmark_index(1);
  const int m = 5;
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(m, n);
  H.middleCols(0, 12) = Eigen::MatrixXd::Random(m, 12);                       // both poses
  H.middleCols(state.landmark_index(2), 3) = Eigen::MatrixXd::Random(m, 3);  // an active object
  const Eigen::MatrixXd V = testing::random_spd(m, random, 0.5, 1.0);
  const Eigen::VectorXd r = testing::random_vector(m, random);
  const Eigen::MatrixXd P = state.covariance;
  Eigen::MatrixXd K = P * H.transpose() * (H * P * H.transpose() + V).inverse();
  K.middleRows(held, 3).setZero();
  const Eigen::MatrixXd I_KH = Eigen::MatrixXd::Identity(n, n) - K * H;
  const Eigen::MatrixXd expected = I_KH * P * I_KH.transpose() + K * V * K.transpose();
  const Eigen::VectorXd correction = K * r;

  const State before = state;
  ASSERT_TRUE(StateHelper::update(state, H, r, V));
  EXPECT_TRUE(state.covariance.isApprox(expected, 1e-10));
  const Eigen::Matrix3d held_block = state.covariance.block<3, 3>(held, held);
  EXPECT_TRUE((held_block.array() == P.block<3, 3>(held, held).array()).all());
  EXPECT_EQ(state.landmarks[1].p_world, before.landmarks[1].p_world);
  EXPECT_FALSE(state.covariance.middleCols(held, 3).isApprox(P.middleCols(held, 3), 1e-3));
  EXPECT_TRUE(state.landmarks[2].p_world.isApprox(
      before.landmarks[2].p_world + correction.segment<3>(state.landmark_index(2)), 1e-10));
  const Eigen::LLT<Eigen::MatrixXd> positive(state.covariance);
  EXPECT_EQ(positive.info(), Eigen::Success);

  // The same update with the object active again moves it: the gain rows are back.
  State active = before;
  active.landmarks[1].archived = false;
  ASSERT_TRUE(StateHelper::update(active, H, r, V));
  EXPECT_FALSE(active.landmarks[1].p_world.isApprox(before.landmarks[1].p_world, 1e-6));
}

TEST(Augmentation, MatchesEquation30) {
  std::mt19937 random(14);
  State state = testing::random_state(2, 1, random);
  const State before = state;
  const int n = state.dimension();
  Eigen::MatrixXd H1 = Eigen::MatrixXd::Zero(3, n);
  H1.leftCols(12) = Eigen::MatrixXd::Random(3, 12);
  Eigen::Matrix3d R1 = Eigen::Matrix3d::Random().triangularView<Eigen::Upper>();
  R1.diagonal() = Eigen::Vector3d(2.0, 1.5, 3.0);
  const Eigen::Matrix3d V1 = 0.1 * Eigen::Matrix3d::Identity();
  StateHelper::augment_landmark(state, 7, Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(1, 2, 2.9),
                                1, H1, R1, V1);
  ASSERT_EQ(state.dimension(), n + 3);
  const Eigen::Matrix3d R1i = R1.inverse();
  const Eigen::MatrixXd expected_cross = -before.covariance * H1.transpose() * R1i.transpose();
  const Eigen::Matrix3d expected_block =
      R1i * (H1 * before.covariance * H1.transpose() + V1) * R1i.transpose();
  EXPECT_TRUE(state.covariance.topLeftCorner(n, n).isApprox(before.covariance));
  EXPECT_TRUE(state.covariance.block(0, n, n, 3).isApprox(expected_cross, 1e-12));
  const Eigen::Matrix3d block = state.covariance.block<3, 3>(n, n);
  EXPECT_TRUE(block.isApprox(expected_block, 1e-12));
  EXPECT_EQ(state.landmark_slot(7), 1);
  EXPECT_TRUE(state.landmarks[1].p_linearization.isApprox(Eigen::Vector3d(1, 2, 2.9)));
}

/// Every column of H (rows of a measurement, columns of the state) against central differences
/// of `predict` when the state moves by a small correction along that column (apply_correction:
/// the filter's own retraction).
template <typename Predict>
void expect_state_columns_match(const State& state, const Eigen::MatrixXd& H, Predict&& predict) {
  const double h = 1e-6;
  for (int column = 0; column < state.dimension(); ++column) {
    State plus = state, minus = state;
    StateHelper::apply_correction(plus, h * Eigen::VectorXd::Unit(state.dimension(), column));
    StateHelper::apply_correction(minus, -h * Eigen::VectorXd::Unit(state.dimension(), column));
    const Eigen::VectorXd numeric = (predict(plus) - predict(minus)) / (2 * h);
    const Eigen::VectorXd analytic = H.col(column);
    EXPECT_LT((numeric - analytic).norm(), 1e-6 * (1.0 + analytic.norm()))
        << "column " << column << ": numeric " << numeric.transpose() << " analytic "
        << analytic.transpose();
  }
}

// Two observations of in-state landmark 1 from poses 0 and 2 of a three-pose window: every
// column of H_state (all poses, the disparity offset if there is one, all landmarks) against the
// change of the predicted observations when the state moves by a small correction
// (apply_correction: the filter's own retraction).
void check_full_assembly(bool with_disparity_offset) {
  const StereoCamera camera = kitti_like_camera();
  std::mt19937 random(15);
  State state;
  for (int k = 0; k < 3; ++k) {
    Eigen::Isometry3d pose = lie::se3_exp(testing::random_vector(6, random, 0.05));
    pose.translation() += Eigen::Vector3d(1.0 * k, 0.0, 0.0);
    state.poses.push_back({k, pose});
  }
  for (int j = 0; j < 2; ++j) {
    const Eigen::Vector3d p_world(14.0 + 3.0 * j, -1.0 + j, 0.5);
    state.landmarks.push_back({10 + j, p_world, 0, p_world});
  }
  if (with_disparity_offset) {
    state.has_disparity_offset = true;
    state.disparity_offset = 0.3;  // pixels: the right image's u reads 0.3 px high
  }
  state.rebuild_landmark_index();
  state.covariance = Eigen::MatrixXd::Identity(state.dimension(), state.dimension());
  const int slot = 1;
  std::vector<TrackObservation> track;
  for (int frame : {0, 2}) {
    const auto projection = UpdaterHelper::project(
        camera, state.poses[frame].T_world_body, state.landmarks[slot].p_world);
    ASSERT_TRUE(projection);
    track.push_back({frame, projection->xy + testing::random_vector(4, random, 1e-3)});
  }
  const auto linearized =
      UpdaterHelper::linearize(state, camera, track, state.landmarks[slot].p_world, slot);
  ASSERT_TRUE(linearized);
  ASSERT_EQ(linearized->H_state.cols(), state.dimension());
  const auto predict = [&](const State& s) {
    Eigen::VectorXd xy(8);
    for (int i = 0; i < 2; ++i) {
      xy.segment<4>(4 * i) = UpdaterHelper::project(camera,
                                                    s.poses[track[i].frame].T_world_body,
                                                    s.landmarks[slot].p_world)
                                 ->xy;
      // The model: u_right = u_right(true) + d, in normalized units d / fx.
      if (s.has_disparity_offset) xy(4 * i + 2) += s.disparity_offset / camera.K(0, 0);
    }
    return xy;
  };
  expect_state_columns_match(state, linearized->H_state, predict);
  // The residual is the observation minus the prediction.
  Eigen::VectorXd observed(8);
  for (int i = 0; i < 2; ++i) observed.segment<4>(4 * i) = track[i].xy;
  EXPECT_TRUE(linearized->residual.isApprox(observed - predict(state), 1e-12));
  if (with_disparity_offset) {
    // The offset's column is there (not all zero) and landmarks sit after it.
    EXPECT_GT(linearized->H_state.col(state.disparity_offset_index()).norm(), 0.0);
    EXPECT_EQ(state.landmark_index(0), state.disparity_offset_index() + 1);
  }
}

TEST(Linearization, FullAssemblyMatchesFiniteDifferencesOfTheState) {
  check_full_assembly(false);
}

TEST(Linearization, FullAssemblyWithADisparityOffsetStateMatchesFiniteDifferences) {
  check_full_assembly(true);
}

TEST(Linearization, LevelMeasurementMatchesFiniteDifferencesOfTheState) {
  // A three-pose window with a disparity offset, a world up axis tilted off its reference and a
  // landmark: every column of the level measurement's H against the change of
  // h = [a b]^T (R_newest u - w) (a, b fixed at the estimate) under the filter's own retraction.
  std::mt19937 random(21);
  State state = testing::random_state(3, 1, random);
  for (PoseClone& pose : state.poses) {
    pose.T_world_body = lie::se3_exp(testing::random_vector(6, random, 0.1)) * pose.T_world_body;
  }
  state.has_disparity_offset = true;
  state.has_world_up = true;
  state.world_up = WorldUp::around(Eigen::Vector3d(0.05, -0.02, 1.0));
  state.world_up.tilt = Eigen::Vector2d(0.03, -0.01);
  state.covariance = Eigen::MatrixXd::Identity(state.dimension(), state.dimension());
  const Eigen::Vector3d axis = Eigen::Vector3d(-0.02, 0.01, 1.0).normalized();
  Eigen::MatrixXd H;
  Eigen::VectorXd residual;
  UpdaterHelper::linearize_level(state, axis, H, residual);
  ASSERT_EQ(H.rows(), 2);
  ASSERT_EQ(H.cols(), state.dimension());
  const Eigen::Vector3d w = state.world_up.direction();
  Eigen::Matrix<double, 2, 3> across;
  across.row(0) = w.unitOrthogonal().transpose();
  across.row(1) = w.cross(w.unitOrthogonal()).transpose();
  const auto h = [&](const State& s) -> Eigen::Vector2d {
    return across * (s.newest_pose().T_world_body.linear() * axis - s.world_up.direction());
  };
  EXPECT_TRUE(residual.isApprox(-h(state), 1e-12));
  EXPECT_GT(residual.norm(), 0.01);  // tilted against each other: the residual is not trivial
  expect_state_columns_match(state, H, [&](const State& s) -> Eigen::VectorXd { return h(s); });
  // Only the newest pose's rotation and the tilt enter.
  EXPECT_GT(H.middleCols<3>(state.pose_index(2) + 3).norm(), 0.5);
  EXPECT_GT(H.middleCols<2>(state.world_up_index()).norm(), 0.5);
  EXPECT_NEAR(H.norm() * H.norm(), H.middleCols<3>(state.pose_index(2) + 3).squaredNorm() +
                                        H.middleCols<2>(state.world_up_index()).squaredNorm(),
              1e-12);
}

TEST(StereoNoise, CovarianceOfTheComponentsAndWhitening) {
  const StereoCamera camera = kitti_like_camera();
  const StereoNoise noise{20.0, 4.0, 2.0, 0.5};
  const Eigen::Matrix4d covariance = UpdaterHelper::observation_covariance(noise, camera);
  const double fx = camera.K(0, 0), fy = camera.K(1, 1);
  // The common mode (u_l + u_r) / 2 has the horizontal variance, u_l - u_r the disparity one.
  const Eigen::Vector4d common(0.5, 0.0, 0.5, 0.0), disparity(1.0, 0.0, -1.0, 0.0);
  const Eigen::Vector4d vertical(0.0, 0.5, 0.0, 0.5), vertical_difference(0.0, 1.0, 0.0, -1.0);
  EXPECT_NEAR(common.dot(covariance * common) * fx * fx, 400.0, 1e-9);
  EXPECT_NEAR(disparity.dot(covariance * disparity) * fx * fx, 4.0, 1e-9);
  EXPECT_NEAR(vertical.dot(covariance * vertical) * fy * fy, 16.0, 1e-9);
  EXPECT_NEAR(vertical_difference.dot(covariance * vertical_difference) * fy * fy, 0.25, 1e-9);
  EXPECT_NEAR(common.dot(covariance * disparity), 0.0, 1e-15);
  // Isotropic noise is independent per coordinate.
  const Eigen::Matrix4d isotropic =
      UpdaterHelper::observation_covariance(StereoNoise::isotropic(3.0), camera);
  EXPECT_NEAR(isotropic(0, 2), 0.0, 1e-15);
  EXPECT_NEAR(isotropic(0, 0) * fx * fx, 9.0, 1e-9);
  // Whitening: W C W^T = I.
  const Eigen::Matrix4d W = UpdaterHelper::whitening(covariance);
  EXPECT_TRUE((W * covariance * W.transpose()).isApprox(Eigen::Matrix4d::Identity(), 1e-9));
}

}  // namespace
}  // namespace concord
