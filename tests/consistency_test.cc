// Consistency of the filter (issue: honest uncertainty): a Monte-Carlo NEES test on the simulator
// with the sensor config, the NEES computation on hand-computed cases, the failure counters, and
// the calibration of a sensor with known noise.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <algorithm>
#include <boost/math/distributions/chi_squared.hpp>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <limits>
#include <map>
#include <random>

#include "calibration/calibration.h"
#include "concord/config/options_file.h"
#include "concord/dataset/result_io.h"
#include "concord/estimator/consensus.h"
#include "concord/estimator/estimator.h"
#include "concord/estimator/lie.h"
#include "concord/estimator/object_updater.h"
#include "concord/estimator/state_helper.h"
#include "concord/estimator/updater_helper.h"
#include "evaluation/metrics.h"
#include "replay/team_replay.h"
#include "sim/simulator.h"
#include "test_support.h"

namespace concord {
namespace {

const std::string kSimConfig = std::string(CONCORD_SOURCE_DIR) + "/configs/sensors/sim.yaml";

/// The interval that holds the mean of `samples` independent chi2(dof) draws with probability
/// `probability` (two-sided).
std::pair<double, double> mean_interval(int samples, int dof, double probability) {
  const boost::math::chi_squared sum(static_cast<double>(samples * dof));
  const double tail = 0.5 * (1.0 - probability);
  return {boost::math::quantile(sum, tail) / samples,
          boost::math::quantile(boost::math::complement(sum, tail)) / samples};
}

struct MonteCarlo {
  std::vector<double> pose;    ///< final-frame pose NEES of robot 0 of each seed
  std::vector<double> object;  ///< NEES of robot 0's final objects of each seed, all pooled
};

/// One simulated team without point features, replayed with `options`.
struct SimulatedRun {
  dataset::Dataset data;
  replay::ReplayResult result;
};
SimulatedRun simulate_and_replay(sim::SimulationOptions simulation,
                                 const EstimatorOptions& options, bool consensus) {
  simulation.points_per_frame = 0;
  SimulatedRun run{sim::simulate(simulation), {}};
  replay::ReplayOptions replay_options;
  replay_options.consensus = consensus;
  run.result = replay::run_team(run.data, options, replay_options);
  return run;
}

/// Short runs of a simulated team, one per seed, with the checked-in sensor config. Only robot 0
/// of each run enters, so that the samples are independent (robots of one team are not, once
/// they exchange marginals).
MonteCarlo monte_carlo(bool consensus, int seeds, int robots, int frames) {
  const EstimatorOptions options = config::load_estimator_options(kSimConfig);
  MonteCarlo out;
  for (int seed = 1; seed <= seeds; ++seed) {
    sim::SimulationOptions simulation;
    simulation.robots = robots;
    simulation.frames = frames;
    simulation.seed = static_cast<std::uint64_t>(seed);
    const SimulatedRun run = simulate_and_replay(simulation, options, consensus);
    const dataset::Dataset& data = run.data;
    const replay::RobotOutput& robot = run.result.robots.front();
    const auto& truth = data.robots.front().groundtruth;
    out.pose.push_back(
        evaluation::pose_nees(robot.trajectory.back(), robot.pose_covariances.back(), truth.back())
            .pose);
    for (const ObjectEstimate& object : robot.objects) {
      out.object.push_back(evaluation::point_nees(object.p_world, object.covariance,
                                                  data.objects_groundtruth.at(object.id)));
    }
  }
  return out;
}

double mean(const std::vector<double>& values) {
  double sum = 0.0;
  for (double value : values) sum += value;
  return sum / static_cast<double>(values.size());
}

TEST(MonteCarloNees, SeparateRobotsPosesAreConsistent) {
  // 20 seeds: the mean final pose NEES of independent runs must lie in the 99.9 % interval of
  // the mean of 20 chi2(6) draws ([3.7, 8.9]); measured about 8.4, a mild overconfidence left by
  // the stereo depth's nonlinearity (docs/results-consistency.md). Without the left-invariant
  // errors and first-estimate Jacobians it is several times that.
  const MonteCarlo runs = monte_carlo(false, 20, 1, 120);
  const auto [low, high] = mean_interval(static_cast<int>(runs.pose.size()), 6, 0.999);
  EXPECT_GT(mean(runs.pose), low);
  EXPECT_LT(mean(runs.pose), high);
  // Objects of one run share the robot's trajectory error, so they are not independent samples:
  // check the mean against a wider band around 3 instead of the chi-square interval.
  EXPECT_GT(mean(runs.object), 1.5);
  EXPECT_LT(mean(runs.object), 6.0);
}

TEST(MonteCarloNees, ConsensusPosesAreConsistentAndObjectsNotOverconfident) {
  const MonteCarlo runs = monte_carlo(true, 20, 3, 120);
  const auto [low, high] = mean_interval(static_cast<int>(runs.pose.size()), 6, 0.999);
  EXPECT_GT(mean(runs.pose), low);
  EXPECT_LT(mean(runs.pose), high);
  // The consensus average (a geometric mean) is conservative: objects may be under- but never
  // over-confident.
  EXPECT_LT(mean(runs.object), 6.0);
}

TEST(FirstEstimateNoise, IsWhatTheFirstEstimateJacobianLeavesOutOfThePrediction) {
  // The pose Jacobians at the estimate (UpdaterHelper::project) and at a first estimate
  // elsewhere differ on the rotation only; under a pose covariance, that difference's covariance
  // is the term object_first_estimate_noise adds to an observation's noise.
  std::mt19937 random(11);
  const StereoCamera camera = testing::kitti_like_camera();
  for (int trial = 0; trial < 20; ++trial) {
    const Eigen::Vector3d rotation = testing::random_vector(3, random, 0.3);
    Eigen::Isometry3d T_world_body = Eigen::Isometry3d::Identity();
    T_world_body.linear() = lie::so3_exp(rotation);
    T_world_body.translation() = testing::random_vector(3, random, 2.0);
    // An object 4-12 m ahead of the left camera, and a first estimate about a metre off it.
    std::uniform_real_distribution<double> across(-1.0, 1.0), depth(4.0, 12.0);
    const Eigen::Vector3d in_camera(across(random), 0.5 * across(random), depth(random));
    const Eigen::Vector3d p_world = T_world_body * (camera.T_cam0_body.inverse() * in_camera);
    const Eigen::Vector3d p_linearization = p_world + testing::random_vector(3, random, 1.0);
    const auto at_estimate = UpdaterHelper::project(camera, T_world_body, p_world);
    ASSERT_TRUE(at_estimate.has_value());
    const Eigen::Matrix<double, 4, 6> difference =
        at_estimate->jacobian_pose -
        UpdaterHelper::pose_jacobian(at_estimate->jacobian_point, p_linearization);
    const Eigen::MatrixXd pose_covariance = testing::random_spd(6, random, 1e-4, 1e-2);
    const Eigen::Matrix4d expected = difference * pose_covariance * difference.transpose();
    const Eigen::Matrix4d noise =
        UpdaterHelper::first_estimate_noise(at_estimate->jacobian_point, p_linearization, p_world,
                                            pose_covariance.bottomRightCorner<3, 3>());
    EXPECT_TRUE(noise.isApprox(expected, 1e-9)) << noise << "\n\n" << expected;
    EXPECT_GT(noise.trace(), 0.0);
    // At the estimate itself nothing is left out.
    EXPECT_TRUE(UpdaterHelper::first_estimate_noise(at_estimate->jacobian_point, p_world, p_world,
                                                    pose_covariance.bottomRightCorner<3, 3>())
                    .isZero(0.0));
  }
}

/// Robot 0 of `seeds` separate single-robot runs with doubled odometry noise (the config's
/// sigmas doubled with it): the mean pose NEES over every frame and the RMS position error.
struct PooledRun {
  double pose_nees = 0.0;
  double position_rms = 0.0;
};
PooledRun separate_runs_with_doubled_odometry(const EstimatorOptions& base, int seeds, int frames) {
  EstimatorOptions options = base;
  options.odometry_translation_sigma *= 2.0;
  options.odometry_rotation_sigma *= 2.0;
  double nees = 0.0, squared = 0.0;
  int samples = 0;
  for (int seed = 1; seed <= seeds; ++seed) {
    sim::SimulationOptions simulation;
    simulation.robots = 1;
    simulation.frames = frames;
    simulation.seed = static_cast<std::uint64_t>(100 + seed);
    simulation.odometry_translation_noise *= 2.0;
    simulation.odometry_rotation_noise *= 2.0;
    const SimulatedRun run = simulate_and_replay(simulation, options, false);
    const replay::RobotOutput& robot = run.result.robots.front();
    const auto& truth = run.data.robots.front().groundtruth;
    for (std::size_t k = 0; k < robot.trajectory.size(); ++k) {
      nees += evaluation::pose_nees(robot.trajectory[k], robot.pose_covariances[k], truth[k]).pose;
      squared += (robot.trajectory[k].translation() - truth[k].translation()).squaredNorm();
      ++samples;
    }
  }
  return {nees / samples, std::sqrt(squared / samples)};
}

TEST(FirstEstimateNoise, MakesSeparateRunsLessOverconfidentAtNoCostInAccuracy) {
  // With a heading uncertain by degrees, an object's first-estimate Jacobians are off by J [d]x
  // on a rotation error the filter knows to be large; counted as noise (the sensor config's
  // default, 1) the separate runs' pose NEES comes down and their accuracy stays.
  EstimatorOptions with = config::load_estimator_options(kSimConfig);
  ASSERT_EQ(with.object_first_estimate_noise, 1.0);
  EstimatorOptions without = with;
  without.object_first_estimate_noise = 0.0;
  const PooledRun a = separate_runs_with_doubled_odometry(with, 12, 300);
  const PooledRun b = separate_runs_with_doubled_odometry(without, 12, 300);
  std::cout << "pose NEES " << a.pose_nees << " (without the term " << b.pose_nees
            << "), position RMS " << a.position_rms << " m (" << b.position_rms << " m)\n";
  EXPECT_LT(a.pose_nees, 0.95 * b.pose_nees);
  EXPECT_LT(a.position_rms, 1.05 * b.position_rms);
}

TEST(Nees, HandComputedPoseAndPointCases) {
  // Truth = estimate * exp(xi) with xi = (0.2, 0, 0, 0, 0, 0.1); covariance diag(0.01 ... ,
  // 0.04 ... ): NEES = 0.2^2 / 0.01 + 0.1^2 / 0.04 = 4.25, position 4, orientation 0.25.
  const Eigen::Isometry3d estimate =
      lie::se3_exp((lie::Vector6d() << 1.0, 2.0, 3.0, 0.3, -0.2, 0.1).finished());
  const lie::Vector6d xi = (lie::Vector6d() << 0.2, 0.0, 0.0, 0.0, 0.0, 0.1).finished();
  const Eigen::Isometry3d truth = estimate * lie::se3_exp(xi);
  lie::Matrix6d covariance = lie::Matrix6d::Zero();
  covariance.diagonal() << 0.01, 0.01, 0.01, 0.04, 0.04, 0.04;
  const evaluation::PoseNees nees = evaluation::pose_nees(estimate, covariance, truth);
  EXPECT_NEAR(nees.pose, 4.25, 1e-9);
  EXPECT_NEAR(nees.position, 4.0, 1e-9);
  EXPECT_NEAR(nees.orientation, 0.25, 1e-9);
  EXPECT_TRUE(std::isnan(evaluation::pose_nees(estimate, -covariance, truth).pose));
  // Point: error (1, 2, 0) under diag(1, 4, 9): 1 + 1 = 2.
  EXPECT_NEAR(
      evaluation::point_nees(Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(1.0, 4.0, 9.0).asDiagonal(),
                             Eigen::Vector3d(0, 0, 3)),
      2.0, 1e-12);
}

TEST(Nees, SummaryCountsTheBoundAndTheQuarters) {
  // chi2(3) 95 % bound is 7.815: 7 of 8 samples inside; first quarter {1, 2}, last {9, 3}.
  const evaluation::NeesSummary summary = evaluation::summarize_nees(
      {1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 9.0, 3.0, std::numeric_limits<double>::quiet_NaN()}, 3);
  EXPECT_EQ(summary.samples, 8);
  EXPECT_NEAR(summary.mean, 33.0 / 8.0, 1e-12);
  EXPECT_NEAR(summary.median, 3.5, 1e-12);
  EXPECT_NEAR(summary.inside_95, 7.0 / 8.0, 1e-12);
  EXPECT_NEAR(summary.first_quarter_median, 1.5, 1e-12);
  EXPECT_NEAR(summary.last_quarter_median, 6.0, 1e-12);
  EXPECT_EQ(evaluation::summarize_nees({}, 6).samples, 0);
}

TEST(Nees, EvaluationReportsPoseAndObjectNeesFromTheCovariances) {
  // One robot, two frames, estimate = truth except a 0.3 m error along x at frame 1 with
  // variance 0.09 (NEES 1 in 3-D position, 1 in 6-D); one object off by 0.2 m with variance 0.04.
  evaluation::RobotTruth truth;
  truth.groundtruth = {Eigen::Isometry3d::Identity(), Eigen::Isometry3d::Identity()};
  evaluation::RobotResult result;
  result.trajectory = truth.groundtruth;
  result.trajectory[1].translation().x() = 0.3;
  lie::Matrix6d covariance = 0.09 * lie::Matrix6d::Identity();
  result.pose_covariances = {covariance, covariance};
  result.objects.push_back({7, Eigen::Vector3d(0.2, 0, 0), 0.04 * Eigen::Matrix3d::Identity()});
  const auto metrics = evaluation::evaluate({truth}, {result}, {{7, Eigen::Vector3d::Zero()}});
  EXPECT_EQ(metrics.robots[0].pose_nees.samples, 2);
  EXPECT_NEAR(metrics.robots[0].pose_nees.mean, 0.5, 1e-9);
  EXPECT_NEAR(metrics.robots[0].object_nees.mean, 1.0, 1e-9);
  // Pose covariances of the wrong length are an error that names the robot.
  result.pose_covariances.pop_back();
  EXPECT_THROW(evaluation::evaluate({truth}, {result}, {}), std::invalid_argument);
}

TEST(PoseCovarianceCsv, RoundTripsAndNamesBadLines) {
  const auto folder = std::filesystem::temp_directory_path() / "concord_pose_covariance_test";
  std::filesystem::create_directories(folder);
  std::mt19937 random(3);
  const Eigen::MatrixXd random_spd = testing::random_spd(6, random);
  const Eigen::MatrixXd spd = 0.5 * (random_spd + random_spd.transpose());
  const std::vector<dataset::PoseCovariance> written = {{0, spd}, {1, 2.0 * spd}};
  const auto file = folder / "pose_covariance.csv";
  dataset::write_pose_covariances_csv(file, written);
  const auto read = dataset::read_pose_covariances_csv(file);
  ASSERT_EQ(read.size(), 2u);
  EXPECT_EQ(read[1].frame, 1);
  EXPECT_TRUE(read[1].covariance.isApprox(2.0 * spd, 0.0));
  dataset::write_file_atomically(file, "frame,c00\n0,1\n");
  EXPECT_THROW(dataset::read_pose_covariances_csv(file), dataset::DatasetError);
  std::filesystem::remove_all(folder);
}

TEST(FailureCounters, AnInconsistentNewObjectIsGatedAndCounted) {
  // A robot drives straight past an object; its third observation is off by 40 px in the left
  // image only (a wrong association): triangulation still succeeds under a generous RMS limit,
  // but the chi-square test of the rows that do not involve the object rejects it.
  const StereoCamera camera = testing::kitti_like_camera();
  EstimatorOptions options;
  options.object_noise = StereoNoise::isotropic(1.0);
  options.object_init_max_reprojection_error = 1000.0;
  options.object_min_observations = 3;
  Estimator estimator(options, camera, Eigen::Isometry3d::Identity());
  const Eigen::Vector3d p_object(15.0, 3.0, 0.5);
  Eigen::Isometry3d truth = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d step = Eigen::Isometry3d::Identity();
  step.translation() = Eigen::Vector3d(0.8, 0.0, 0.0);
  int gated = 0, initialized = 0;
  for (int frame = 0; frame < 3; ++frame) {
    FrameInput input = testing::straight_drive_frame(frame, step, truth);
    Eigen::Vector4d uv = camera.denormalize(UpdaterHelper::project(camera, truth, p_object)->xy);
    if (frame == 2) uv(0) += 40.0;
    input.objects.push_back({3, uv});
    const FrameReport report = estimator.process(input);
    gated += report.objects.init_gated;
    initialized += report.objects.initialized;
  }
  EXPECT_EQ(gated, 1);
  EXPECT_EQ(initialized, 0);
  EXPECT_TRUE(estimator.objects().empty());
}

/// Errors of a detection's box centre (pixels: common horizontal, common vertical, disparity,
/// vertical disparity) made of an independent part, a part constant along the object's track and
/// a part that follows an AR(1) process of lag-1 correlation `correlation`.
struct DetectionErrorModel {
  Eigen::Vector4d independent, constant, persistent;
  double correlation = 0.0;
  /// A displacement in space of the point the detections are centred on (metres, along the
  /// camera's x, y, z): drawn at the first frame, then walking by `displacement_walk` a frame.
  Eigen::Vector3d displacement = Eigen::Vector3d::Zero();
  Eigen::Vector3d displacement_walk = Eigen::Vector3d::Zero();
};

struct ObjectRunStatistics {
  double mean_nees = 0.0;
  double rms_error = 0.0;
};

/// A robot drives straight past one object (40 frames, exact odometry), observing it every frame
/// with errors drawn from `truth`, filtered with `options`; over `runs` seeds: the final object's
/// NEES (mean) and position error (RMS).
ObjectRunStatistics object_runs(const DetectionErrorModel& truth, const EstimatorOptions& options,
                                int runs) {
  const StereoCamera camera = testing::kitti_like_camera();
  const Eigen::Vector3d p_object(26.0, 4.0, 0.5);
  double nees_sum = 0.0, squared_error_sum = 0.0;
  int evaluated = 0;
  for (int run = 0; run < runs; ++run) {
    std::mt19937 random(static_cast<std::uint32_t>(1000 + run));
    std::normal_distribution<double> normal(0.0, 1.0);
    const auto draw = [&](const Eigen::Vector4d& sigma) {
      return Eigen::Vector4d(sigma[0] * normal(random), sigma[1] * normal(random),
                             sigma[2] * normal(random), sigma[3] * normal(random));
    };
    const Eigen::Vector4d constant = draw(truth.constant);
    Eigen::Vector4d persistent = draw(truth.persistent);
    const auto draw3 = [&](const Eigen::Vector3d& sigma) {
      return Eigen::Vector3d(sigma[0] * normal(random), sigma[1] * normal(random),
                             sigma[2] * normal(random));
    };
    // The camera's axes in the world (the robot drives straight: they do not turn).
    const Eigen::Matrix3d R_world_camera = camera.T_cam0_body.linear().transpose();
    Eigen::Vector3d displacement = R_world_camera * draw3(truth.displacement);
    Estimator estimator(options, camera, Eigen::Isometry3d::Identity());
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    Eigen::Isometry3d step = Eigen::Isometry3d::Identity();
    step.translation() = Eigen::Vector3d(0.5, 0.0, 0.0);
    for (int frame = 0; frame < 40; ++frame) {
      FrameInput input = testing::straight_drive_frame(frame, step, pose);
      if (frame > 0) {
        persistent = truth.correlation * persistent +
                     std::sqrt(1.0 - truth.correlation * truth.correlation) * draw(truth.persistent);
        displacement += R_world_camera * draw3(truth.displacement_walk);
      }
      const Eigen::Vector4d e = constant + persistent + draw(truth.independent);
      // (common, vertical, disparity, vertical disparity) to (u_l, v_l, u_r, v_r).
      const Eigen::Vector4d error(e[0] + 0.5 * e[2], e[1] + 0.5 * e[3], e[0] - 0.5 * e[2],
                                  e[1] - 0.5 * e[3]);
      const Eigen::Vector4d uv =
          camera.denormalize(UpdaterHelper::project(camera, pose, p_object + displacement)->xy) +
          error;
      input.objects.push_back({7, uv});
      estimator.process(input);
    }
    const std::vector<ObjectEstimate> objects = estimator.objects();
    if (objects.size() != 1) continue;
    nees_sum += evaluation::point_nees(objects[0].p_world, objects[0].covariance, p_object);
    squared_error_sum += (objects[0].p_world - p_object).squaredNorm();
    ++evaluated;
  }
  EXPECT_EQ(evaluated, runs);
  return {nees_sum / std::max(evaluated, 1), std::sqrt(squared_error_sum / std::max(evaluated, 1))};
}

/// Options for object_runs: a window that holds the whole track, exact poses, every
/// observation counted (no gate): the detection model alone is tested.
EstimatorOptions single_object_options() {
  EstimatorOptions options;
  options.window_size = 40;
  options.use_point_features = false;
  options.initial_position_sigma = 1e-6;
  options.initial_rotation_sigma = 1e-6;
  options.odometry_translation_sigma = 1e-5;
  options.odometry_rotation_sigma = 1e-6;
  options.object_min_distance = 1.0;
  options.object_max_distance = 100.0;
  options.object_init_max_reprojection_error = 50.0;
  options.object_chi2_probability = 0.0;
  return options;
}

/// 200 runs past one object with errors drawn from `truth`: filtered with `modelled` (the
/// window holds the whole track, so an exact model is consistent) the object's NEES lies in the
/// chi-square interval; with `independent` (the errors taken as independent) 40 observations
/// claim far more than they know; and the model's weighting is not less accurate.
void expect_the_model_honest_where_independent_noise_is_not(const DetectionErrorModel& truth,
                                                           const EstimatorOptions& modelled,
                                                           const EstimatorOptions& independent) {
  const int runs = 200;
  const ObjectRunStatistics as_independent = object_runs(truth, independent, runs);
  const ObjectRunStatistics as_modelled = object_runs(truth, modelled, runs);
  const auto [low, high] = mean_interval(runs, 3, 0.99);
  EXPECT_GT(as_modelled.mean_nees, low);
  EXPECT_LT(as_modelled.mean_nees, high);
  EXPECT_GT(as_independent.mean_nees, 3.0 * high);
  EXPECT_LT(as_modelled.rms_error, 1.05 * as_independent.rms_error)
      << as_modelled.rms_error << " vs " << as_independent.rms_error;
}

StereoNoise as_noise(const Eigen::Vector4d& sigma) {
  return {sigma[0], sigma[1], sigma[2], sigma[3]};
}

TEST(PersistentDetectionError, ModelledItKeepsTheObjectHonestWhereIndependentNoiseIsOverconfident) {
  // Box centres off by an amount that stays along the track (1.5 px), plus a part that changes
  // slowly (1 px, correlation 0.8 a frame) and a little independent jitter.
  DetectionErrorModel truth;
  truth.independent = Eigen::Vector4d(0.5, 0.5, 0.3, 0.3);
  truth.constant = Eigen::Vector4d(1.5, 1.5, 0.4, 0.0);
  truth.persistent = Eigen::Vector4d(1.0, 1.0, 0.5, 0.0);
  truth.correlation = 0.8;
  EstimatorOptions options = single_object_options();
  // As independent noise of the same total size per coordinate.
  EstimatorOptions independent = options;
  independent.object_noise = as_noise(
      (truth.independent.array().square() + truth.constant.array().square() +
       truth.persistent.array().square())
          .sqrt()
          .matrix());
  // As it is.
  EstimatorOptions modelled = options;
  modelled.object_noise = as_noise(truth.independent);
  modelled.object_noise_constant = as_noise(truth.constant);
  modelled.object_noise_persistent = as_noise(truth.persistent);
  modelled.object_noise_correlation = truth.correlation;
  expect_the_model_honest_where_independent_noise_is_not(truth, modelled, independent);
}

TEST(DetectionOffset, AStateForAnOffsetThatStaysAlongTheTrackKeepsTheObjectHonest) {
  // Box centres off by an amount that stays along the track (1.5 px in x and y, the same in
  // both images), plus independent jitter: the offset, as a state of the robot's filter, is
  // this error's exact model.
  DetectionErrorModel truth;
  truth.independent = Eigen::Vector4d(0.5, 0.5, 0.3, 0.3);
  truth.constant = Eigen::Vector4d(1.5, 1.5, 0.0, 0.0);
  truth.persistent = Eigen::Vector4d::Zero();
  EstimatorOptions options = single_object_options();
  options.object_noise = as_noise(truth.independent);
  EstimatorOptions with_offset = options;
  with_offset.object_offset_sigma = {1.5, 1.5, 0.01, 0.0};
  ASSERT_TRUE(with_offset.validate().empty());
  expect_the_model_honest_where_independent_noise_is_not(truth, with_offset, options);
}

TEST(DetectionDisplacement, AStateForADisplacementInSpaceKeepsTheObjectHonest) {
  // Detections centred on a point 0.3 m (across), 0.2 m (vertically) and 0.6 m (in depth) off
  // the object's centre, drawn once and then walking a few centimetres a frame, plus a little
  // independent jitter: in the image the error grows as the robot nears the object (26 m to
  // 6 m), which an image offset or independent noise does not describe. The displacement, as a
  // state, is this error's exact model.
  DetectionErrorModel truth;
  truth.independent = Eigen::Vector4d(0.5, 0.5, 0.3, 0.3);
  truth.constant = truth.persistent = Eigen::Vector4d::Zero();
  truth.displacement = Eigen::Vector3d(0.3, 0.2, 0.6);
  truth.displacement_walk = Eigen::Vector3d(0.02, 0.01, 0.04);
  EstimatorOptions options = single_object_options();
  options.object_noise = as_noise(truth.independent);
  EstimatorOptions modelled = options;
  modelled.object_displacement_sigma = {0.3, 0.2, 0.6};
  modelled.object_displacement_walk = {0.02, 0.01, 0.04};
  ASSERT_TRUE(modelled.validate().empty());
  expect_the_model_honest_where_independent_noise_is_not(truth, modelled, options);
}

TEST(DetectionDisplacement, TurnsWithTheWorldFrameAndIsNoObject) {
  const StereoCamera camera = testing::kitti_like_camera();
  EstimatorOptions options;
  options.use_point_features = false;
  options.object_noise = StereoNoise::isotropic(1.0);
  options.object_displacement_sigma = {0.2, 0.1, 0.5};
  options.object_displacement_walk = {0.01, 0.01, 0.02};
  Estimator estimator(options, camera, Eigen::Isometry3d::Identity());
  const Eigen::Vector3d p_object(15.0, 3.0, 0.5), d_true(0.1, -0.05, 0.2);
  Eigen::Isometry3d truth = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d step = Eigen::Isometry3d::Identity();
  step.translation() = Eigen::Vector3d(0.5, 0.0, 0.0);
  for (int frame = 0; frame < 8; ++frame) {
    FrameInput input = testing::straight_drive_frame(frame, step, truth);
    input.objects.push_back(
        {3, camera.denormalize(UpdaterHelper::project(camera, truth, p_object + d_true)->xy)});
    (void)estimator.process(input);
  }
  const State& state = estimator.state();
  const int slot = state.offset_slot(3);
  ASSERT_GE(slot, 0);
  EXPECT_TRUE(state.landmarks[slot].detection_offset);
  EXPECT_TRUE(state.landmarks[slot].displacement);
  EXPECT_EQ(estimator.objects().size(), 1u);
  EXPECT_EQ(state.object_ids(), std::vector<LandmarkId>{3});
  // One robot cannot tell the object from the displacement: the object's covariance keeps at
  // least what the displacement's prior says along the camera's axes (x right = -y world here,
  // y down = -z, z forward = +x), less only what the walk-free first frames could not add.
  const int object = state.landmark_index(state.landmark_slot(3));
  const Eigen::Matrix3d R_world_camera = camera.T_cam0_body.linear().transpose();
  const Eigen::Matrix3d in_camera =
      R_world_camera.transpose() * state.covariance.block<3, 3>(object, object) * R_world_camera;
  EXPECT_GT(std::sqrt(in_camera(0, 0)), 0.9 * 0.2);
  EXPECT_GT(std::sqrt(in_camera(1, 1)), 0.9 * 0.1);
  EXPECT_GT(std::sqrt(in_camera(2, 2)), 0.9 * 0.5);
  // The object plus the displacement is what the detections saw.
  EXPECT_LT((state.landmarks[state.landmark_slot(3)].p_world + state.landmarks[slot].p_world -
             (p_object + d_true))
                .norm(),
            0.05);
  // A change of world frame turns the displacement (a direction), with its covariance; the
  // transform's rotation uncertainty adds to it, its translation does not.
  State moved = state;
  const int index = moved.landmark_index(slot);
  const Eigen::Vector3d d = moved.landmarks[slot].p_world;
  const Eigen::Matrix3d covariance = moved.covariance.block<3, 3>(index, index);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(4.0, -2.0, 0.3);
  StateHelper::reanchor(moved, T, lie::Matrix6d::Zero());
  EXPECT_TRUE(moved.landmarks[slot].p_world.isApprox(T.linear() * d, 1e-12));
  const Eigen::Matrix3d turned = moved.covariance.block<3, 3>(index, index);
  EXPECT_TRUE(turned.isApprox(T.linear() * covariance * T.linear().transpose(), 1e-9));
  State translated = state;
  Eigen::Isometry3d shift = Eigen::Isometry3d::Identity();
  shift.translation() = Eigen::Vector3d(1.0, 2.0, 3.0);
  lie::Matrix6d translation_only = lie::Matrix6d::Zero();
  translation_only.topLeftCorner<3, 3>().setIdentity();
  StateHelper::reanchor(translated, shift, translation_only);
  EXPECT_EQ(translated.landmarks[slot].p_world, d);
  const Eigen::Matrix3d kept = translated.covariance.block<3, 3>(index, index);
  EXPECT_TRUE(kept.isApprox(covariance, 1e-12));
  // A state that holds displacements needs options that make them, and not image offsets.
  EXPECT_NO_THROW(Estimator(options, camera, state));
  EstimatorOptions offsets = options;
  offsets.object_displacement_sigma = {};
  offsets.object_displacement_walk = {};
  offsets.object_offset_sigma = StereoNoise::isotropic(1.0);
  EXPECT_THROW(Estimator(offsets, camera, state), std::invalid_argument);
  EstimatorOptions neither = offsets;
  neither.object_offset_sigma = StereoNoise::isotropic(0.0);
  EXPECT_THROW(Estimator(neither, camera, state), std::invalid_argument);
}

TEST(DetectionDisplacement, OptionsRefuseTwoModelsOfOneErrorAndBadValues) {
  EstimatorOptions options;
  options.object_displacement_sigma = {0.1, 0.1, 0.2};
  options.object_displacement_walk = {0.01, 0.01, 0.02};
  EXPECT_TRUE(options.validate().empty());
  EstimatorOptions with_offset = options;
  with_offset.object_offset_sigma = StereoNoise::isotropic(1.0);
  EXPECT_FALSE(with_offset.validate().empty());
  EstimatorOptions with_persistent = options;
  with_persistent.object_noise_persistent = StereoNoise::isotropic(1.0);
  EXPECT_FALSE(with_persistent.validate().empty());
  EstimatorOptions walk_only;
  walk_only.object_displacement_walk = {0.01, 0.0, 0.0};
  EXPECT_FALSE(walk_only.validate().empty());
  EstimatorOptions negative = options;
  negative.object_displacement_sigma[1] = -0.1;
  EXPECT_FALSE(negative.validate().empty());
  EstimatorOptions not_finite = options;
  not_finite.object_displacement_walk[2] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(not_finite.validate().empty());
}

TEST(DetectionOffset, IsTheRobotsOwnStateNotAnObjectAndLeavesWithItsObject) {
  const StereoCamera camera = testing::kitti_like_camera();
  EstimatorOptions options;
  options.use_point_features = false;
  options.object_noise = StereoNoise::isotropic(1.0);
  options.object_offset_sigma = StereoNoise::isotropic(2.0);
  options.object_offset_walk = StereoNoise::isotropic(0.2);
  options.object_archive_after_frames = 3;
  options.object_archive_mode = "marginal";
  Estimator estimator(options, camera, Eigen::Isometry3d::Identity());
  const Eigen::Vector3d p_object(15.0, 3.0, 0.5);
  Eigen::Isometry3d truth = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d step = Eigen::Isometry3d::Identity();
  step.translation() = Eigen::Vector3d(0.5, 0.0, 0.0);
  int frame = 0;
  double offset_variance = 0.0;
  for (; frame < 8; ++frame) {
    FrameInput input = testing::straight_drive_frame(frame, step, truth);
    input.objects.push_back(
        {3, camera.denormalize(UpdaterHelper::project(camera, truth, p_object)->xy)});
    (void)estimator.process(input);
    const State& state = estimator.state();
    if (state.landmark_slot(3) < 0) continue;
    // In the joint state beside its object, correlated with it, and nowhere in the outputs.
    const int slot = state.offset_slot(3);
    ASSERT_GE(slot, 0) << frame;
    EXPECT_TRUE(state.landmarks[slot].detection_offset);
    const int index = state.landmark_index(slot);
    const int object = state.landmark_index(state.landmark_slot(3));
    const Eigen::Matrix3d cross = state.covariance.block<3, 3>(index, object);
    EXPECT_GT(cross.norm(), 0.0);
    offset_variance = state.covariance(index, index);
    EXPECT_EQ(estimator.objects().size(), 1u);
    EXPECT_EQ(state.object_ids(), std::vector<LandmarkId>{3});
    const Marginal marginal = Consensus::marginal(state, {3});
    ASSERT_EQ(marginal.ids, std::vector<LandmarkId>{3});
    EXPECT_EQ(marginal.mean.size(), 3);
  }
  EXPECT_GT(offset_variance, 0.0);
  // Moving the state into another frame moves the object, not the offset (image units).
  {
    State moved = estimator.state();
    const int slot = moved.offset_slot(3);
    const Eigen::Vector3d offset = moved.landmarks[slot].p_world;
    const Eigen::Matrix3d offset_covariance =
        moved.covariance.block<3, 3>(moved.landmark_index(slot), moved.landmark_index(slot));
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T.translation() = Eigen::Vector3d(4.0, -2.0, 0.3);
    StateHelper::reanchor(moved, T, lie::Matrix6d::Identity() * 1e-4);
    EXPECT_EQ(moved.landmarks[slot].p_world, offset);
    const int index = moved.landmark_index(slot);
    const Eigen::Matrix3d after = moved.covariance.block<3, 3>(index, index);
    EXPECT_TRUE(after.isApprox(offset_covariance, 1e-12));
  }
  // Not observed: the object is archived and its offset leaves the state.
  for (; frame < 14; ++frame) {
    (void)estimator.process(testing::straight_drive_frame(frame, step, truth));
  }
  EXPECT_LT(estimator.state().landmark_slot(3), 0);
  EXPECT_LT(estimator.state().offset_slot(3), 0);
  EXPECT_EQ(estimator.state().num_landmarks(), 0);
  EXPECT_EQ(estimator.objects().size(), 1u);  // archived
}

TEST(DetectionOffset, OptionsRefuseTwoModelsOfOneError) {
  EstimatorOptions options;
  options.object_offset_sigma = StereoNoise::isotropic(1.0);
  EXPECT_TRUE(options.validate().empty());
  options.object_noise_persistent = StereoNoise::isotropic(1.0);
  EXPECT_FALSE(options.validate().empty());
  EstimatorOptions walk_only;
  walk_only.object_offset_walk = StereoNoise::isotropic(1.0);
  EXPECT_FALSE(walk_only.validate().empty());
  EstimatorOptions negative;
  negative.object_offset_sigma.vertical = -1.0;
  EXPECT_FALSE(negative.validate().empty());
}

TEST(FailureCounters, AnUpdateWithAnIndefiniteInnovationIsRefusedAndLeavesTheState) {
  std::mt19937 random(4);
  State state = testing::random_state(2, 1, random);
  const State before = state;
  const Eigen::MatrixXd H = Eigen::MatrixXd::Identity(2, state.dimension());
  const Eigen::MatrixXd noise = -100.0 * Eigen::MatrixXd::Identity(2, 2);
  EXPECT_FALSE(StateHelper::update(state, H, Eigen::VectorXd::Ones(2), noise));
  EXPECT_TRUE(state.covariance.isApprox(before.covariance, 0.0));
}

/// Angle (radians) between the body's up axis (+z) in the world and the world's +z.
double tilt(const Eigen::Isometry3d& T_world_body) {
  const Eigen::Vector3d up = T_world_body.linear() * Eigen::Vector3d::UnitZ();
  return std::acos(std::clamp(up.z(), -1.0, 1.0));
}

TEST(LevelPrior, TakesTheKalmanShareOfATiltAndLeavesTheHeading) {
  // One step turns the robot 0.3 rad about the vertical and pitches it 0.05 rad. The odometry's
  // rotation noise is 0.1 rad; the level prior's is 0.1 rad and the world's up axis, which the
  // start frame gives up to its own tilt, is uncertain by as much: the measurement's noise is
  // twice the odometry's variance, so the update takes about a third of the tilt away and leaves
  // the heading alone.
  EstimatorOptions options;
  options.odometry_rotation_sigma = 0.1;
  options.level_sigma = 0.1;
  options.use_objects = false;
  options.use_point_features = false;
  Estimator estimator(options, testing::kitti_like_camera(), Eigen::Isometry3d::Identity());
  FrameInput start;
  estimator.process(start);
  FrameInput step;
  step.frame = 1;
  Eigen::Isometry3d motion = Eigen::Isometry3d::Identity();
  motion.linear() = (Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()) *
                     Eigen::AngleAxisd(0.05, Eigen::Vector3d::UnitY()))
                        .toRotationMatrix();
  step.T_previous_current = motion;
  const FrameReport report = estimator.process(step);
  EXPECT_TRUE(report.level_applied);
  EXPECT_FALSE(report.level_failed);
  const Eigen::Isometry3d pose = estimator.current_pose();
  const double prior = 0.1 * 0.1 + 1e-6;  // odometry and the start's 1 mrad
  const double measurement = 0.1 * 0.1 + 0.1 * 0.1;  // the level prior and the world's up axis
  EXPECT_NEAR(tilt(pose), 0.05 * (measurement / (prior + measurement)), 1e-3);
  const Eigen::Vector3d forward = pose.linear() * Eigen::Vector3d::UnitX();
  EXPECT_NEAR(std::atan2(forward.y(), forward.x()), 0.3, 1e-3);
  // The tilt's variance shrinks by the same share; the heading's stays the odometry's.
  const Eigen::Matrix3d rotation = estimator.current_pose_covariance().bottomRightCorner<3, 3>();
  const Eigen::Vector3d vertical = pose.linear().transpose() * Eigen::Vector3d::UnitZ();
  EXPECT_NEAR(vertical.dot(rotation * vertical), prior, 1e-4);
  const Eigen::Vector3d across = pose.linear().transpose() * Eigen::Vector3d::UnitX();
  EXPECT_NEAR(across.dot(rotation * across), prior * measurement / (prior + measurement), 1e-4);
}

TEST(LevelPrior, BoundsThePitchThatBiasedOdometryLetsDrift) {
  // The odometry reads 2 mrad of pitch a frame that the robot does not make: dead reckoning
  // tilts by 0.6 rad in 300 frames; with the prior every 10th frame the tilt stays bounded, and
  // the frames between are left alone.
  for (const double sigma : {0.0, 0.02}) {
    EstimatorOptions options;
    options.odometry_rotation_sigma = 0.002;
    options.level_sigma = sigma;
    options.level_every_frames = 10;
    options.use_objects = false;
    options.use_point_features = false;
    Estimator estimator(options, testing::kitti_like_camera(), Eigen::Isometry3d::Identity());
    estimator.process(FrameInput{});
    Eigen::Isometry3d motion = Eigen::Isometry3d::Identity();
    motion.translation() = Eigen::Vector3d(0.8, 0.0, 0.0);
    motion.linear() = Eigen::AngleAxisd(0.002, Eigen::Vector3d::UnitY()).toRotationMatrix();
    int applied = 0;
    double tilt_halfway = 0.0;
    for (int frame = 1; frame <= 300; ++frame) {
      FrameInput input;
      input.frame = frame;
      input.T_previous_current = motion;
      const FrameReport report = estimator.process(input);
      EXPECT_EQ(report.level_applied, sigma > 0.0 && frame % 10 == 0);
      applied += report.level_applied;
      if (frame == 150) tilt_halfway = tilt(estimator.current_pose());
    }
    if (sigma == 0.0) {
      EXPECT_NEAR(tilt(estimator.current_pose()), 0.6, 1e-6);
    } else {
      EXPECT_EQ(applied, 30);
      // Bounded, not growing with the run: the world's up axis, free within its prior, takes up
      // part of the drift (its share grows with the drift's length, then stops).
      EXPECT_LT(tilt(estimator.current_pose()), 0.12);
      EXPECT_LT(tilt(estimator.current_pose()), 1.5 * tilt_halfway);
    }
  }
}

TEST(LevelPrior, FindsTheUpAxisOfAStartFrameOnASlope) {
  // The robot starts on a 0.04 rad slope, so its start frame, the world frame, is tilted against
  // gravity by that much; then it drives off onto level ground and turns, with exact odometry.
  // The level measurements keep showing the body's axis tilted against the start's: the world's
  // up axis (a state) takes that up, and the poses stay where the odometry puts them instead of
  // being pulled towards the start's tilted level.
  const double slope = 0.04;
  const Eigen::Vector3d gravity_up =
      Eigen::AngleAxisd(slope, Eigen::Vector3d::UnitY()) * Eigen::Vector3d::UnitZ();
  const auto truth = [&](int frame) {
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    if (frame < 10) return pose;  // on the slope
    // Level: the body's z along gravity's up, heading turning.
    pose.linear() = Eigen::AngleAxisd(slope, Eigen::Vector3d::UnitY()).toRotationMatrix() *
                    Eigen::AngleAxisd(0.02 * frame, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    pose.translation() = Eigen::Vector3d(0.8 * frame, 0.0, 0.0);
    return pose;
  };
  EstimatorOptions options;
  options.odometry_translation_sigma = 0.01;
  options.odometry_rotation_sigma = 0.001;
  options.level_sigma = slope;  // the start's slope is one draw of the tilt
  options.level_every_frames = 5;
  options.use_objects = false;
  options.use_point_features = false;
  Estimator estimator(options, testing::kitti_like_camera(), truth(0));
  estimator.process(FrameInput{});
  const double start_error = std::acos(estimator.state().world_up.direction().dot(gravity_up));
  EXPECT_NEAR(start_error, slope, 1e-9);
  double worst_tilt_error = 0.0;
  for (int frame = 1; frame <= 300; ++frame) {
    FrameInput input;
    input.frame = frame;
    input.T_previous_current = truth(frame - 1).inverse() * truth(frame);
    ASSERT_FALSE(estimator.process(input).level_failed);
    const Eigen::Vector3d body_z = estimator.current_pose().linear() * Eigen::Vector3d::UnitZ();
    const Eigen::Vector3d true_z = truth(frame).linear() * Eigen::Vector3d::UnitZ();
    worst_tilt_error = std::max(worst_tilt_error, std::acos(std::min(1.0, body_z.dot(true_z))));
  }
  const State& state = estimator.state();
  const double end_error = std::acos(std::min(1.0, state.world_up.direction().dot(gravity_up)));
  EXPECT_LT(end_error, 0.2 * slope);
  // Within its own uncertainty (the larger tilt sigma, three of them).
  const Eigen::Matrix2d tilt_covariance =
      state.covariance.block<2, 2>(state.world_up_index(), state.world_up_index());
  EXPECT_LT(end_error, 3.0 * std::sqrt(tilt_covariance.eigenvalues().real().maxCoeff()));
  // The poses keep the odometry's exact attitude to within a fraction of the slope.
  EXPECT_LT(worst_tilt_error, 0.25 * slope);
}

TEST(LevelPrior, OptionsAreChecked) {
  EstimatorOptions options;
  options.level_sigma = -1.0;
  options.level_every_frames = 0;
  options.level_up_axis = {0.0, 0.0, 0.0};
  const std::vector<std::string> problems = options.validate();
  ASSERT_EQ(problems.size(), 3u);
  EXPECT_NE(problems[0].find("level_sigma"), std::string::npos);
  EXPECT_NE(problems[1].find("level_every_frames"), std::string::npos);
  EXPECT_NE(problems[2].find("level_up_axis"), std::string::npos);
  EXPECT_EQ(body_axis_vector("-y"), (std::array<double, 3>{0.0, -1.0, 0.0}));
  EXPECT_EQ(body_axis_vector("+z"), (std::array<double, 3>{0.0, 0.0, 1.0}));
  EXPECT_EQ(body_axis_vector("z"), (std::array<double, 3>{0.0, 0.0, 0.0}));
  EXPECT_EQ(body_axis_vector("+w"), (std::array<double, 3>{0.0, 0.0, 0.0}));
}

/// A short simulated robot with objects only, for the restore and odometry-noise tests.
dataset::Dataset one_robot(int frames) {
  sim::SimulationOptions simulation;
  simulation.robots = 1;
  simulation.frames = frames;
  simulation.seed = 11;
  simulation.objects = 50;  // placed along these few frames: the state stays small
  simulation.points_per_frame = 0;
  return sim::simulate(simulation);
}

TEST(Resume, AnEstimatorRestoredFromItsStateContinuesExactlyAsTheOriginal) {
  const dataset::Dataset data = one_robot(60);
  const EstimatorOptions options = config::load_estimator_options(kSimConfig);
  const dataset::RobotData& robot = data.robots.front();
  Estimator original(options, data.camera, robot.groundtruth.front());
  for (int frame = 0; frame < 30; ++frame) (void)original.process(robot.frame_input(frame));
  ASSERT_FALSE(original.objects().empty());
  Estimator restored(options, data.camera, original.state(), original.pending_objects());
  for (int frame = 30; frame < 60; ++frame) {
    (void)original.process(robot.frame_input(frame));
    (void)restored.process(robot.frame_input(frame));
  }
  EXPECT_TRUE(restored.state().covariance.isApprox(original.state().covariance, 0.0));
  EXPECT_TRUE(restored.state().newest_pose().T_world_body.isApprox(
      original.state().newest_pose().T_world_body, 0.0));
  EXPECT_EQ(restored.objects().size(), original.objects().size());
}

/// One simulated robot's separate run with the sim config and the given archive mode: the mean
/// pose NEES over the last quarter of the run, and what archiving did.
struct ArchiveRun {
  double last_quarter_pose_nees = 0.0;
  int archived = 0;
  int reactivated = 0;
  State state;
};
ArchiveRun run_with_archive_mode(const std::string& mode, int seed) {
  sim::SimulationOptions simulation;
  simulation.robots = 1;
  simulation.frames = 300;
  simulation.seed = seed;
  simulation.points_per_frame = 0;
  const dataset::Dataset data = sim::simulate(simulation);
  const dataset::RobotData& robot = data.robots.front();
  EstimatorOptions options = config::load_estimator_options(kSimConfig);
  options.object_archive_mode = mode;
  Estimator estimator(options, data.camera, robot.groundtruth.front());
  ArchiveRun out;
  const int last_quarter = simulation.frames - simulation.frames / 4;
  for (int frame = 0; frame < simulation.frames; ++frame) {
    const FrameReport report = estimator.process(robot.frame_input(frame));
    out.archived += report.objects.archived;
    out.reactivated += report.objects.reactivated;
    if (frame < last_quarter) continue;
    out.last_quarter_pose_nees += evaluation::pose_nees(estimator.current_pose(),
                                                        estimator.current_pose_covariance(),
                                                        robot.groundtruth[frame])
                                      .pose /
                                  (simulation.frames - last_quarter);
  }
  out.state = estimator.state();
  return out;
}

TEST(Archiving, ConsiderStatesRejoinWithTheirCorrelationsAndKeepThePosesHonest) {
  // Seeds not used while developing (41, which sees no object again in 300 frames, left out).
  // With object_archive_mode marginal, an object seen again is fused back as if its old
  // marginal were independent of the poses, and pose NEES grows through a run; as Schmidt
  // consider states the objects keep their correlations. Per seed it goes either way (the last
  // quarter is 75 frames of one robot): the mean of five is asserted.
  double marginal = 0.0, consider = 0.0;
  const std::vector<int> seeds = {42, 43, 44, 45, 46};
  for (int seed : seeds) {
    const ArchiveRun m = run_with_archive_mode("marginal", seed);
    const ArchiveRun c = run_with_archive_mode("consider", seed);
    // Both archive and see objects again; consider keeps every object in the joint state.
    EXPECT_GT(c.archived, 0) << seed;
    EXPECT_GT(c.reactivated, 0) << seed;
    EXPECT_GT(m.reactivated, 0) << seed;
    EXPECT_TRUE(c.state.archived.empty()) << seed;
    EXPECT_FALSE(m.state.archived.empty()) << seed;
    EXPECT_TRUE(std::any_of(c.state.landmarks.begin(), c.state.landmarks.end(),
                            [](const ObjectLandmark& l) { return l.archived; }))
        << seed;
    EXPECT_EQ(Eigen::LLT<Eigen::MatrixXd>(c.state.covariance).info(), Eigen::Success) << seed;
    marginal += m.last_quarter_pose_nees / static_cast<double>(seeds.size());
    consider += c.last_quarter_pose_nees / static_cast<double>(seeds.size());
  }
  EXPECT_LT(consider, marginal);
  EXPECT_LT(consider, boost::math::quantile(boost::math::chi_squared(6), 0.95));
  std::cout << "last-quarter pose NEES, mean of " << seeds.size() << " seeds: marginal "
            << marginal << ", consider " << consider << "\n";
}

TEST(Archiving, AnArchivedObjectKeepsItsCovarianceRelativeToThePoseOfThatMoment) {
  // Marginal archiving: the object leaves the joint state as its marginal, and with it the
  // covariance conditioned on the newest pose, P_oo - P_op P_pp^-1 P_po (what the robot knew of
  // it relative to itself). The other object stays.
  std::mt19937 random(31);
  State state = testing::random_state(3, 2, random);
  for (int i = 0; i < 3; ++i) state.poses[i].frame = 40 + i;
  state.landmarks[1].last_observed_frame = 42;
  const State before = state;
  EstimatorOptions options = config::load_estimator_options(kSimConfig);
  ASSERT_EQ(options.object_archive_mode, "marginal");
  ASSERT_LT(options.object_archive_after_frames, 42);
  ObjectUpdater updater(options, one_robot(2).camera);
  const ObjectUpdateStats stats = updater.process(state, {});
  EXPECT_EQ(stats.archived, 1);
  ASSERT_EQ(state.archived.count(100), 1u);
  ASSERT_EQ(state.num_landmarks(), 1);
  const int pose = before.pose_index(2), object = before.landmark_index(0);
  const Eigen::MatrixXd& P = before.covariance;
  const Eigen::Matrix3d marginal = P.block<3, 3>(object, object);
  const Eigen::Matrix3d expected = marginal - P.block<3, 6>(object, pose) *
                                                  P.block<6, 6>(pose, pose).inverse() *
                                                  P.block<6, 3>(pose, object);
  EXPECT_TRUE(state.archived.at(100).covariance.isApprox(marginal, 1e-12));
  ASSERT_EQ(state.archived_local_covariance.count(100), 1u);
  EXPECT_TRUE(state.archived_local_covariance.at(100).isApprox(expected, 1e-10));
  EXPECT_EQ(state.archived_local_covariance.count(101), 0u);

  // A move into another frame turns it with the frame and adds nothing of the transform's
  // uncertainty (which the marginal takes).
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(0.8, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(3, -1, 0.5);
  State moved = state;
  StateHelper::reanchor(moved, T, 0.01 * lie::Matrix6d::Identity());
  EXPECT_TRUE(moved.archived_local_covariance.at(100).isApprox(
      T.linear() * expected * T.linear().transpose(), 1e-10));
  EXPECT_GT(moved.archived.at(100).covariance.trace(), marginal.trace() + 0.01);
}

/// Frames of archiving_run.
constexpr int kArchivingFrames = 300;

/// One simulated robot of kArchivingFrames frames, objects only (the archiving tests' runs).
dataset::Dataset archiving_run(std::uint64_t seed) {
  sim::SimulationOptions simulation;
  simulation.robots = 1;
  simulation.frames = kArchivingFrames;
  simulation.seed = seed;
  simulation.points_per_frame = 0;
  return sim::simulate(simulation);
}

TEST(Archiving, AnOldMarginalThatDisagreesWithTheFreshEstimateIsNotFusedBack) {
  // A separate run with marginal archiving, resumed at frame 150 from its own state twice: as it
  // was, and with every archived object's marginal moved 4 m sideways and made certain to 5 cm
  // (as if a team had averaged it with a wrong merge). Seen again, an object whose old marginal
  // is that far from its fresh estimate is not fused back (covariance intersection would take
  // the certain old marginal and drag the whole state by the conditional): the rejoins are
  // refused and counted, and the run ends near the untouched one. The untouched one refuses
  // none.
  const dataset::Dataset data = archiving_run(53);  // seed not used while developing
  const dataset::RobotData& robot = data.robots.front();
  const EstimatorOptions options = config::load_estimator_options(kSimConfig);
  Estimator first_half(options, data.camera, robot.groundtruth.front());
  const int resume = 150;
  for (int frame = 0; frame < resume; ++frame) (void)first_half.process(robot.frame_input(frame));
  ASSERT_GT(first_half.state().archived.size(), 5u);
  State moved = first_half.state();
  for (auto& [id, estimate] : moved.archived) {
    estimate.p_world += Eigen::Vector3d(0.0, 4.0, 0.0);
    estimate.covariance = 0.05 * 0.05 * Eigen::Matrix3d::Identity();
  }

  const auto finish = [&](State state, int& reactivated, int& refused) -> Eigen::Vector3d {
    Estimator estimator(options, data.camera, std::move(state), first_half.pending_objects());
    reactivated = refused = 0;
    for (int frame = resume; frame < kArchivingFrames; ++frame) {
      const FrameReport report = estimator.process(robot.frame_input(frame));
      reactivated += report.objects.reactivated;
      refused += report.objects.rejoins_refused;
    }
    return Eigen::Vector3d(estimator.current_pose().translation());
  };
  int reactivated = 0, refused = 0;
  const Eigen::Vector3d untouched = finish(first_half.state(), reactivated, refused);
  EXPECT_GE(reactivated, 3);
  EXPECT_EQ(refused, 0);
  const Eigen::Vector3d end = finish(moved, reactivated, refused);
  EXPECT_GE(refused, 3);
  const Eigen::Vector3d truth = robot.groundtruth.back().translation();
  std::cout << "end position error: untouched " << (untouched - truth).norm() << " m, with the "
            << "moved marginals " << (end - truth).norm() << " m (" << refused
            << " rejoins refused)\n";
  // Fused back, the 4 m would drag the end by about as much (measured: 3.95 m off the truth,
  // 0.09 m untouched); refused, the run loses only those objects' old information.
  EXPECT_LT((end - untouched).norm(), 1.0);
}

TEST(Archiving, ObjectsArchivedTogetherKnowTheirRelativeGeometryBetterThanTheirMarginalsSay) {
  // A separate run with marginal archiving. For two objects archived at the same frame, the
  // error of their difference is free of the drift both share; the recorded covariances
  // (relative to the pose of that moment) are smaller than the marginals by that drift and
  // still cover it. An object that rejoined the state keeps no stale entry.
  const dataset::Dataset data = archiving_run(47);  // seed not used while developing
  const dataset::RobotData& robot = data.robots.front();
  const EstimatorOptions options = config::load_estimator_options(kSimConfig);
  Estimator estimator(options, data.camera, robot.groundtruth.front());
  for (int frame = 0; frame < kArchivingFrames; ++frame)
    (void)estimator.process(robot.frame_input(frame));
  const State& state = estimator.state();
  ASSERT_GT(state.archived.size(), 10u);
  double local_trace = 0.0, marginal_trace = 0.0;
  for (const auto& [id, local] : state.archived_local_covariance) {
    ASSERT_EQ(state.archived.count(id), 1u) << id;
    EXPECT_LT(state.landmark_slot(id), 0) << id;
    const Eigen::Matrix3d& marginal = state.archived.at(id).covariance;
    EXPECT_TRUE(Eigen::LDLT<Eigen::Matrix3d>(marginal - local).isPositive()) << id;
    local_trace += local.trace();
    marginal_trace += marginal.trace();
  }
  EXPECT_GE(state.archived_local_covariance.size(), state.archived.size() * 9 / 10);
  EXPECT_LT(local_trace, 0.5 * marginal_trace);
  // The pairs' normalized errors: consistent under the local covariances, far below 3 under the
  // marginals (which count the shared drift twice).
  double local_nees = 0.0, marginal_nees = 0.0;
  int pairs = 0;
  for (const auto& [a, local_a] : state.archived_local_covariance) {
    for (const auto& [b, local_b] : state.archived_local_covariance) {
      if (b <= a || state.archived_last_observed.at(a) != state.archived_last_observed.at(b))
        continue;
      const Eigen::Vector3d error =
          (state.archived.at(a).p_world - state.archived.at(b).p_world) -
          (data.objects_groundtruth.at(a) - data.objects_groundtruth.at(b));
      local_nees += error.dot((local_a + local_b).ldlt().solve(error));
      marginal_nees += error.dot(
          (state.archived.at(a).covariance + state.archived.at(b).covariance).ldlt().solve(error));
      ++pairs;
    }
  }
  ASSERT_GT(pairs, 5);
  local_nees /= pairs;
  marginal_nees /= pairs;
  std::cout << pairs << " pairs archived together: mean NEES of their difference " << local_nees
            << " under the recorded covariances, " << marginal_nees << " under the marginals\n";
  EXPECT_LT(local_nees, boost::math::quantile(boost::math::chi_squared(3), 0.95));
  EXPECT_LT(marginal_nees, local_nees);
}

TEST(Resume, AStateWhoseShapesDisagreeIsRefused) {
  const dataset::Dataset data = one_robot(10);
  const EstimatorOptions options = config::load_estimator_options(kSimConfig);
  Estimator estimator(options, data.camera, data.robots.front().groundtruth.front());
  for (int frame = 0; frame < 10; ++frame)
    (void)estimator.process(data.robots.front().frame_input(frame));
  State bad = estimator.state();
  bad.covariance.conservativeResize(bad.covariance.rows() - 1, bad.covariance.cols() - 1);
  EXPECT_THROW(Estimator(options, data.camera, bad), std::invalid_argument);
  State gap = estimator.state();
  gap.poses.back().frame += 2;
  EXPECT_THROW(Estimator(options, data.camera, gap), std::invalid_argument);
}

TEST(Resume, AStateWithADisparityOffsetNeedsTheOptionsThatMadeIt) {
  const dataset::Dataset data = one_robot(10);
  EstimatorOptions options = config::load_estimator_options(kSimConfig);
  options.disparity_offset_sigma = 0.05;
  Estimator estimator(options, data.camera, data.robots.front().groundtruth.front());
  for (int frame = 0; frame < 10; ++frame)
    (void)estimator.process(data.robots.front().frame_input(frame));
  ASSERT_TRUE(estimator.state().has_disparity_offset);
  EXPECT_NO_THROW(Estimator(options, data.camera, estimator.state()));
  options.disparity_offset_sigma = 0.0;
  EXPECT_THROW(Estimator(options, data.camera, estimator.state()), std::invalid_argument);
}

/// Final position error and mean pose NEES over a run of one simulated robot whose every stereo
/// observation has its right u shifted by `offset` (a calibration error shared by all tracks).
struct OffsetRun {
  double position_error_rms = 0.0;
  double mean_pose_nees = 0.0;
  State state;
};
OffsetRun run_with_disparity_offset(double offset, double prior_sigma) {
  sim::SimulationOptions simulation;
  simulation.robots = 1;
  simulation.frames = 150;
  simulation.seed = 5;
  simulation.objects = 60;
  simulation.points_per_frame = 30;
  dataset::Dataset data = sim::simulate(simulation);
  dataset::RobotData& robot = data.robots.front();
  for (auto& frame : robot.features) {
    for (StereoObservation& observation : frame) observation.uv(2) += offset;
  }
  for (auto& frame : robot.objects) {
    for (StereoObservation& observation : frame) observation.uv(2) += offset;
  }
  EstimatorOptions options = config::load_estimator_options(kSimConfig);
  options.disparity_offset_sigma = prior_sigma;
  Estimator estimator(options, data.camera, robot.groundtruth.front());
  OffsetRun out;
  double squared = 0.0;
  for (int frame = 0; frame < simulation.frames; ++frame) {
    (void)estimator.process(robot.frame_input(frame));
    const Eigen::Vector3d error =
        estimator.current_pose().translation() - robot.groundtruth[frame].translation();
    squared += error.squaredNorm();
    out.mean_pose_nees += evaluation::pose_nees(estimator.current_pose(),
                                                estimator.current_pose_covariance(),
                                                robot.groundtruth[frame])
                              .pose;
  }
  out.position_error_rms = std::sqrt(squared / simulation.frames);
  out.mean_pose_nees /= simulation.frames;
  out.state = estimator.state();
  return out;
}

TEST(DisparityOffset, AnOffsetSharedByEveryTrackIsEstimatedAndKeepsTheFilterHonest) {
  // The simulator's observations are in normalized units (K = I) with 0.01 noise per coordinate;
  // an offset of twice that on every right u is what a slightly wrong rectification does.
  const double offset = 0.02;
  const OffsetRun ignored = run_with_disparity_offset(offset, 0.0);
  const OffsetRun estimated = run_with_disparity_offset(offset, 0.05);
  ASSERT_TRUE(estimated.state.has_disparity_offset);
  const int index = estimated.state.disparity_offset_index();
  const double sigma = std::sqrt(estimated.state.covariance(index, index));
  // Learned from the data (well inside the prior), and the truth within 3 sigma of it.
  EXPECT_LT(sigma, 0.05 / 5.0);
  EXPECT_LT(std::abs(estimated.state.disparity_offset - offset), 3.0 * sigma)
      << "estimate " << estimated.state.disparity_offset << " +- " << sigma;
  // Modelled, the shared error no longer biases the trajectory nor inflates the NEES.
  EXPECT_LT(estimated.position_error_rms, ignored.position_error_rms);
  EXPECT_LT(estimated.mean_pose_nees, ignored.mean_pose_nees);
  // Without an offset in the data the state stays near zero and changes nothing much.
  const OffsetRun none = run_with_disparity_offset(0.0, 0.05);
  const int none_index = none.state.disparity_offset_index();
  EXPECT_LT(std::abs(none.state.disparity_offset),
            3.0 * std::sqrt(none.state.covariance(none_index, none_index)));
}

TEST(OdometryCovariance, APerFrameCovarianceReplacesTheConfiguredNoise) {
  const dataset::Dataset data = one_robot(2);
  EstimatorOptions options = config::load_estimator_options(kSimConfig);
  options.object_noise = StereoNoise::isotropic(1.0);
  FrameInput first = data.robots.front().frame_input(0);
  FrameInput second = data.robots.front().frame_input(1);
  first.objects.clear();
  second.objects.clear();
  const auto grown = [&](const std::optional<Eigen::Matrix<double, 6, 6>>& covariance) {
    Estimator estimator(options, data.camera, data.robots.front().groundtruth.front());
    (void)estimator.process(first);
    FrameInput input = second;
    input.odometry_covariance = covariance;
    (void)estimator.process(input);
    return estimator.current_pose_covariance();
  };
  // With no landmarks the covariance after one step is the start's plus the step's noise: a
  // per-frame covariance 100x the configured one grows the new pose's uncertainty by about that.
  const Eigen::Matrix<double, 6, 6> configured = grown(std::nullopt);
  Eigen::Matrix<double, 6, 6> large = Eigen::Matrix<double, 6, 6>::Zero();
  large.diagonal() << Eigen::Vector3d::Constant(
      std::pow(100.0 * options.odometry_translation_sigma, 2)),
      Eigen::Vector3d::Constant(std::pow(100.0 * options.odometry_rotation_sigma, 2));
  const Eigen::Matrix<double, 6, 6> given = grown(large);
  EXPECT_GT(given.trace(), 100.0 * configured.trace());
  EXPECT_TRUE(given.allFinite());
  Eigen::Matrix<double, 6, 6> indefinite = -large;
  EXPECT_THROW(grown(indefinite), std::invalid_argument);
}

TEST(ComposedMotion, ItsCovarianceMatchesTheSpreadOfComposedNoisySteps) {
  // Three steps with different noise, composed 20000 times with sampled noise: the sample
  // covariance of the composed motion's right perturbation matches the first-order formula.
  std::mt19937 random(21);
  std::vector<Eigen::Isometry3d> steps(3, Eigen::Isometry3d::Identity());
  std::vector<lie::Matrix6d> covariances;
  for (int j = 0; j < 3; ++j) {
    steps[j] =
        lie::se3_exp((lie::Vector6d() << 1.0 + j, 0.2, -0.1, 0.05, -0.1, 0.3 * j).finished());
    covariances.push_back(1e-4 * testing::random_spd(6, random, 0.2, 2.0));
  }
  ComposedMotion composed;
  for (int j = 0; j < 3; ++j) composed.then(steps[j], covariances[j]);
  const int samples = 20000;
  lie::Matrix6d spread = lie::Matrix6d::Zero();
  for (int i = 0; i < samples; ++i) {
    Eigen::Isometry3d motion = Eigen::Isometry3d::Identity();
    for (int j = 0; j < 3; ++j) {
      const Eigen::LLT<lie::Matrix6d> llt(covariances[j]);
      const lie::Vector6d w = llt.matrixL() * testing::random_vector(6, random);
      motion = motion * steps[j] * lie::se3_exp(-w);
    }
    const lie::Vector6d error = lie::se3_log(composed.motion.inverse() * motion);
    spread += error * error.transpose() / samples;
  }
  EXPECT_EQ(composed.steps, 3);
  // Relative Frobenius error: sampling (about 1 %) plus second-order terms.
  EXPECT_LT((spread - composed.covariance).norm() / composed.covariance.norm(), 0.05);
  // The naive sum of the step covariances is measurably wrong (the rotations move them).
  lie::Matrix6d sum = lie::Matrix6d::Zero();
  for (const auto& covariance : covariances) sum += covariance;
  EXPECT_GT((spread - sum).norm() / sum.norm(), 0.2);
}

TEST(Calibration, RecoversTheSimulatorsNoise) {
  sim::SimulationOptions simulation;
  simulation.robots = 1;
  simulation.frames = 400;
  simulation.points_per_frame = 20;
  simulation.odometry_translation_noise = 0.02;
  simulation.odometry_rotation_noise = 0.005;
  simulation.pixel_noise = 0.01;
  const dataset::Dataset data = sim::simulate(simulation);
  calibration::CalibrationOptions options;
  options.frames = 400;
  const calibration::CalibrationReport report = calibration::calibrate(data, options);
  for (int axis = 0; axis < 3; ++axis) {
    EXPECT_NEAR(report.odometry_rms(axis), 0.02, 0.002) << axis;
    EXPECT_NEAR(report.odometry_rms(3 + axis), 0.005, 0.0005) << axis;
  }
  EXPECT_NEAR(report.translation_scale, 1.0, 0.01);
  // Independent noise of 0.01 per coordinate: common modes 0.0071, differences 0.0141.
  EXPECT_NEAR(report.objects.horizontal, 0.01 / std::sqrt(2.0), 0.001);
  EXPECT_NEAR(report.objects.disparity, 0.01 * std::sqrt(2.0), 0.002);
  EXPECT_NEAR(report.features.vertical, 0.01 / std::sqrt(2.0), 0.001);
  EXPECT_GT(report.features.observations, 1000);
  // White noise: no time-correlation inflation.
  EXPECT_LT(report.objects.correlation_inflation.maxCoeff(), 1.2);
  // The suggested config loads.
  const std::string yaml = calibration::to_yaml(report, options);
  EXPECT_NO_THROW(config::parse_estimator_options(yaml, "calibration"));
  options.frames = 5;
  EXPECT_THROW(calibration::calibrate(data, options), std::invalid_argument);
}

TEST(Calibration, FitsTheTracksDriftWhereTheTriangulatedPointAbsorbsPartOfIt) {
  // Point-feature tracks whose errors (normalized units) are white, 0.002 per coordinate, plus a
  // random slope per track, the same in both images, horizontal and vertical: 0.0004 a frame
  // (about 0.2 px at a 537 px focal length, eight times the rendered tracks' drift). A slope in
  // the columns looks like parallax, so the residuals against the triangulated point keep only
  // part of it; the fit accounts for that exactly. And without the slope, next to no drift.
  // rectified: v_right = v_left exactly (as on KITTI's tracks), one component 0.
  const auto tracks_with = [](double drift, bool rectified = false) {
    sim::SimulationOptions simulation;
    simulation.robots = 1;
    simulation.frames = 400;
    simulation.points_per_frame = 30;
    simulation.point_track_loss = 0.08;
    simulation.pixel_noise = 1e-7;
    dataset::Dataset data = sim::simulate(simulation);
    auto& features = data.robots.front().features;
    std::map<LandmarkId, std::vector<int>> frames;
    for (std::size_t k = 0; k < features.size(); ++k) {
      for (const StereoObservation& o : features[k]) frames[o.id].push_back(static_cast<int>(k));
    }
    std::map<LandmarkId, std::pair<double, Eigen::Vector2d>> slopes;  // mean frame, slope
    std::mt19937 random(17);
    std::normal_distribution<double> normal(0.0, 1.0);
    for (const auto& [id, seen] : frames) {
      double mean = 0.0;
      for (int k : seen) mean += k / static_cast<double>(seen.size());
      slopes[id] = {mean, Eigen::Vector2d(drift * normal(random), drift * normal(random))};
    }
    for (std::size_t k = 0; k < features.size(); ++k) {
      for (StereoObservation& o : features[k]) {
        const auto& [mean, slope] = slopes[o.id];
        const Eigen::Vector2d line = slope * (static_cast<double>(k) - mean);
        for (int i = 0; i < 4; ++i) o.uv(i) += line(i % 2) + 0.002 * normal(random);
        if (rectified) o.uv(3) = o.uv(1);
      }
    }
    calibration::CalibrationOptions options;
    options.frames = 400;
    return std::pair(calibration::calibrate(data, options), options);
  };
  const auto [drifting, options] = tracks_with(0.0004);
  const calibration::FeatureDrift& fit = drifting.feature_drift;
  ASSERT_GT(fit.tracks, 500);
  EXPECT_NEAR(fit.sigma, 0.0004, 0.1 * 0.0004);
  for (int c = 0; c < 4; ++c) EXPECT_NEAR(fit.white(c), 0.002, 0.1 * 0.002) << c;
  // The report offers it, commented, as the model to use instead of the inflated white noise.
  const std::string yaml = calibration::to_yaml(drifting, options);
  const std::size_t at = yaml.find("# feature_drift_sigma: ");
  ASSERT_NE(at, std::string::npos);
  EXPECT_NEAR(std::stod(yaml.substr(at + 23)), fit.sigma, 1e-3 * fit.sigma);
  const calibration::FeatureDrift still = tracks_with(0.0).first.feature_drift;
  EXPECT_LT(still.sigma, 0.1 * 0.0004);
  EXPECT_NEAR(still.white(0), 0.002, 0.1 * 0.002);
  const calibration::FeatureDrift rectified = tracks_with(0.0004, true).first.feature_drift;
  EXPECT_NEAR(rectified.sigma, 0.0004, 0.1 * 0.0004);
  EXPECT_NEAR(rectified.white(3), 0.0, 1e-6);
}

/// One simulated robot's 400 frames of object observations with next to no noise (no point
/// features): the detection errors are the test's to add.
/// Three independent zero-mean Gaussians of standard deviations `sigma` (from `normal`, a
/// standard one).
Eigen::Vector3d gaussian3(const Eigen::Vector3d& sigma, std::normal_distribution<double>& normal,
                          std::mt19937& random) {
  return Eigen::Vector3d(sigma[0] * normal(random), sigma[1] * normal(random),
                         sigma[2] * normal(random));
}

dataset::Dataset objects_of_one_robot() {
  sim::SimulationOptions simulation;
  simulation.robots = 1;
  simulation.frames = 400;
  simulation.points_per_frame = 0;
  simulation.pixel_noise = 1e-6;
  return sim::simulate(simulation);
}

TEST(Calibration, FitsAConstantAndAPersistentPartOfTheDetectionError) {
  // Object detections whose errors (normalized units; common horizontal, common vertical,
  // disparity, vertical disparity) are a part constant along each object's track, an AR(1) part
  // of correlation 0.8 a frame and a little independent noise.
  dataset::Dataset data = objects_of_one_robot();
  const Eigen::Vector4d constant(0.010, 0.006, 0.004, 0.002);
  const Eigen::Vector4d persistent(0.008, 0.008, 0.005, 0.002);
  const Eigen::Vector4d independent(0.002, 0.002, 0.001, 0.001);
  const double correlation = 0.8;
  std::mt19937 random(5);
  std::normal_distribution<double> normal(0.0, 1.0);
  const auto draw = [&](const Eigen::Vector4d& sigma) {
    return Eigen::Vector4d(sigma[0] * normal(random), sigma[1] * normal(random),
                           sigma[2] * normal(random), sigma[3] * normal(random));
  };
  struct TrackError {
    int frame = -10;
    Eigen::Vector4d constant, persistent;
  };
  std::map<LandmarkId, TrackError> errors;
  int observations = 0;
  for (auto& frame_objects : data.robots.front().objects) {
    for (StereoObservation& observation : frame_objects) {
      TrackError& error = errors[observation.id];
      const int frame = static_cast<int>(&frame_objects - data.robots.front().objects.data());
      if (frame != error.frame + 1) {  // a new track
        error.constant = draw(constant);
        error.persistent = draw(persistent);
      } else {
        error.persistent = correlation * error.persistent +
                           std::sqrt(1.0 - correlation * correlation) * draw(persistent);
      }
      error.frame = frame;
      const Eigen::Vector4d e = error.constant + error.persistent + draw(independent);
      observation.uv += Eigen::Vector4d(e[0] + 0.5 * e[2], e[1] + 0.5 * e[3], e[0] - 0.5 * e[2],
                                        e[1] - 0.5 * e[3]);
      ++observations;
    }
  }
  ASSERT_GT(observations, 2000);
  calibration::CalibrationOptions options;
  options.frames = 400;
  const calibration::CalibrationReport report = calibration::calibrate(data, options);
  EXPECT_NEAR(report.objects.persistent_correlation, correlation, 0.1);
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(report.objects.constant(c), constant(c), 0.3 * constant(c)) << c;
    EXPECT_NEAR(report.objects.persistent(c), persistent(c), 0.3 * persistent(c)) << c;
  }
  // The model's keys in the suggested config load.
  std::string yaml = calibration::to_yaml(report, options);
  for (const char* key : {"# object_noise: {", "# object_noise_constant: {",
                          "# object_noise_persistent: {", "# object_noise_correlation: "}) {
    const std::size_t at = yaml.find(key);
    ASSERT_NE(at, std::string::npos) << key;
    yaml.erase(at, 2);  // uncommented
  }
  // The white-noise equivalent (the first object_noise line) gives way to the model's.
  const std::size_t white = yaml.find("object_noise: {");
  yaml.erase(white, yaml.find('\n', white) + 1 - white);
  const EstimatorOptions loaded = config::parse_estimator_options(yaml, "calibration");
  EXPECT_NEAR(loaded.object_noise_correlation, report.objects.persistent_correlation, 1e-3);
  EXPECT_GT(loaded.object_noise_constant.horizontal, 0.0);
}

TEST(Calibration, FitsADetectionOffsetThatWalksAlongEachTrack) {
  // Detections whose errors, in the offset's components (left u, vertical, disparity; normalized
  // units), are an offset drawn at each track's start that walks a little every frame, plus
  // independent noise; a track ends where its object goes unseen for more than 5 frames.
  dataset::Dataset data = objects_of_one_robot();
  const Eigen::Vector3d sigma(0.012, 0.006, 0.004);
  const Eigen::Vector3d walk(0.004, 0.002, 0.0015);
  const Eigen::Vector3d independent(0.002, 0.001, 0.0008);
  std::mt19937 random(9);
  std::normal_distribution<double> normal(0.0, 1.0);
  const auto draw = [&](const Eigen::Vector3d& s) { return gaussian3(s, normal, random); };
  struct Offset {
    int frame = -100;
    Eigen::Vector3d value;
  };
  std::map<LandmarkId, Offset> offsets;
  int observations = 0;
  auto& objects = data.robots.front().objects;
  for (std::size_t frame = 0; frame < objects.size(); ++frame) {
    for (StereoObservation& observation : objects[frame]) {
      Offset& offset = offsets[observation.id];
      const int now = static_cast<int>(frame);
      if (now - offset.frame > 5) {
        offset.value = draw(sigma);
      } else {
        for (int step = offset.frame; step < now; ++step) offset.value += draw(walk);
      }
      offset.frame = now;
      const Eigen::Vector3d e = offset.value + draw(independent);
      // u_left + du, v + dv, u_right = u_left - disparity: + du - dd.
      observation.uv += Eigen::Vector4d(e[0], e[1], e[0] - e[2], e[1]);
      ++observations;
    }
  }
  ASSERT_GT(observations, 2000);
  calibration::CalibrationOptions options;
  options.frames = 400;
  const calibration::CalibrationReport report = calibration::calibrate(data, options);
  ASSERT_GT(report.objects.offset_tracks, 30);
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(report.objects.offset_sigma(c), sigma(c), 0.25 * sigma(c)) << c;
    EXPECT_NEAR(report.objects.offset_walk(c), walk(c), 0.25 * walk(c)) << c;
    EXPECT_NEAR(report.objects.offset_independent(c), independent(c), 0.5 * independent(c)) << c;
  }
  // The model alone loads as an estimator config with exactly those values (to the printed
  // digits), and makes the offset a state.
  const EstimatorOptions loaded = config::parse_estimator_options(
      calibration::detector_model_yaml(report, options,
                                       calibration::DetectorModelKind::kImageOffset),
      "detector model");
  EXPECT_NEAR(loaded.object_offset_sigma.horizontal, report.objects.offset_sigma(0),
              1e-3 * sigma(0));
  EXPECT_NEAR(loaded.object_offset_walk.disparity, report.objects.offset_walk(2), 1e-3 * walk(2));
  EXPECT_NEAR(loaded.object_noise.vertical, report.objects.offset_independent(1),
              1e-3 * independent(1));
  EXPECT_GT(loaded.object_noise.vertical_disparity, 0.0);
  // The full report offers the same keys, commented.
  EXPECT_NE(calibration::to_yaml(report, options).find("# object_offset_walk: {horizontal: "),
            std::string::npos);
  // No objects: nothing to fit, and the model is refused with the reason.
  for (auto& frame : objects) frame.clear();
  const calibration::CalibrationReport empty = calibration::calibrate(data, options);
  EXPECT_EQ(empty.objects.offset_tracks, 0);
  EXPECT_THROW((void)calibration::detector_model_yaml(empty, options), std::invalid_argument);
  options.track_gap = 0;
  EXPECT_THROW(calibration::calibrate(data, options), std::invalid_argument);
  options.track_gap = 5;
  options.offset_max_lag = 1;  // one lag cannot give a line
  EXPECT_THROW(calibration::calibrate(data, options), std::invalid_argument);
}

TEST(Calibration, FitsADetectionDisplacementThatWalksInSpace) {
  // Detections centred on a point off each object's centre by a displacement drawn at the
  // track's start along that camera's axes, walking every frame along the newest camera's,
  // plus a little independent image noise.
  dataset::Dataset data = objects_of_one_robot();
  const Eigen::Vector3d sigma(0.10, 0.05, 0.20);
  const Eigen::Vector3d walk(0.010, 0.005, 0.020);
  std::mt19937 random(21);
  std::normal_distribution<double> normal(0.0, 1.0);
  const auto draw = [&](const Eigen::Vector3d& s) { return gaussian3(s, normal, random); };
  struct Displacement {
    int frame = -100;
    Eigen::Vector3d value;  // world frame
  };
  std::map<LandmarkId, Displacement> displacements;
  dataset::RobotData& robot = data.robots.front();
  int observations = 0;
  for (std::size_t frame = 0; frame < robot.objects.size(); ++frame) {
    const int now = static_cast<int>(frame);
    const Eigen::Matrix3d R_world_camera =
        robot.groundtruth[frame].linear() * data.camera.T_cam0_body.linear().transpose();
    for (StereoObservation& observation : robot.objects[frame]) {
      Displacement& d = displacements[observation.id];
      if (now - d.frame > 5) {
        d.value = R_world_camera * draw(sigma);
      } else {
        for (int step = d.frame; step < now; ++step) d.value += R_world_camera * draw(walk);
      }
      d.frame = now;
      const auto projection =
          UpdaterHelper::project(data.camera, robot.groundtruth[frame],
                                 data.objects_groundtruth.at(observation.id) + d.value);
      ASSERT_TRUE(projection);
      observation.uv =
          data.camera.denormalize(projection->xy) +
          1e-4 * Eigen::Vector4d(normal(random), normal(random), normal(random), normal(random));
      ++observations;
    }
  }
  ASSERT_GT(observations, 2000);
  calibration::CalibrationOptions options;
  options.frames = 400;
  const calibration::CalibrationReport report = calibration::calibrate(data, options);
  const calibration::DetectionDisplacement& fit = report.object_displacement;
  ASSERT_GT(fit.tracks, 30);
  EXPECT_GT(fit.observations, 0.95 * observations);
  for (int axis = 0; axis < 3; ++axis) {
    EXPECT_NEAR(fit.sigma(axis), sigma(axis), 0.25 * sigma(axis)) << axis;
    EXPECT_NEAR(fit.walk(axis), walk(axis), 0.25 * walk(axis)) << axis;
  }
  // The model file (the displacement by default, the image offset on request) loads as an
  // estimator config with those values to the printed digits.
  const EstimatorOptions loaded = config::parse_estimator_options(
      calibration::detector_model_yaml(report, options), "detector model");
  EXPECT_NEAR(loaded.object_displacement_sigma[2], fit.sigma(2), 1e-3 * sigma(2));
  EXPECT_NEAR(loaded.object_displacement_walk[0], fit.walk(0), 1e-3 * walk(0));
  EXPECT_EQ(loaded.object_offset_sigma.horizontal, 0.0);
  const EstimatorOptions as_offset = config::parse_estimator_options(
      calibration::detector_model_yaml(report, options,
                                       calibration::DetectorModelKind::kImageOffset),
      "detector model");
  EXPECT_EQ(as_offset.object_displacement_sigma, (std::array<double, 3>{}));
  EXPECT_GT(as_offset.object_offset_sigma.horizontal, 0.0);
  EXPECT_NE(calibration::to_yaml(report, options).find("# object_displacement_walk: ["),
            std::string::npos);
  // No objects: nothing to fit, and the model is refused with the reason.
  for (auto& frame : robot.objects) frame.clear();
  const calibration::CalibrationReport empty = calibration::calibrate(data, options);
  EXPECT_EQ(empty.object_displacement.tracks, 0);
  EXPECT_THROW((void)calibration::detector_model_yaml(empty, options), std::invalid_argument);
}

TEST(Calibration, FitsTheOffsetsWalkToTheDriftOverTheTracksSpan) {
  // Detections whose error drifts smoothly along each track (an offset and a rate drawn at the
  // track's start: a box centre that slides as the view turns), plus independent noise. Its
  // mean square difference grows with the square of the lag, so a walk (linear in the lag)
  // matches it at one range of lags only; the one that counts is the tracks' span, over which
  // the filter accumulates an object's observations.
  dataset::Dataset data = objects_of_one_robot();
  const Eigen::Vector3d sigma(0.010, 0.005, 0.004);
  const Eigen::Vector3d rate(0.0012, 0.0006, 0.0004);
  const Eigen::Vector3d independent(0.0005, 0.0003, 0.0002);
  std::mt19937 random(13);
  std::normal_distribution<double> normal(0.0, 1.0);
  const auto draw = [&](const Eigen::Vector3d& s) { return gaussian3(s, normal, random); };
  struct Track {
    int start = 0;
    int last = -100;
    Eigen::Vector3d offset, rate;
    std::map<int, Eigen::Vector3d> errors;  // by frame
  };
  std::map<LandmarkId, std::vector<Track>> tracks;
  auto& objects = data.robots.front().objects;
  for (std::size_t frame = 0; frame < objects.size(); ++frame) {
    const int now = static_cast<int>(frame);
    for (StereoObservation& observation : objects[frame]) {
      std::vector<Track>& of_object = tracks[observation.id];
      if (of_object.empty() || now - of_object.back().last > 5) {
        of_object.push_back({now, now, draw(sigma), draw(rate), {}});
      }
      Track& track = of_object.back();
      track.last = now;
      const Eigen::Vector3d e =
          track.offset + static_cast<double>(now - track.start) * track.rate + draw(independent);
      track.errors[now] = e;
      observation.uv += Eigen::Vector4d(e[0], e[1], e[0] - e[2], e[1]);
    }
  }
  // The tracks' span: the median over the observations of their track's first-to-last frames;
  // and the errors' mean square difference at that lag.
  std::vector<int> spans;
  for (const auto& [id, of_object] : tracks) {
    for (const Track& track : of_object) {
      spans.insert(spans.end(), track.errors.size(), track.last - track.start);
    }
  }
  std::nth_element(spans.begin(), spans.begin() + spans.size() / 2, spans.end());
  const int span = spans[spans.size() / 2];
  ASSERT_GE(span, 10);
  Eigen::Vector3d measured = Eigen::Vector3d::Zero();
  int pairs = 0;
  for (const auto& [id, of_object] : tracks) {
    for (const Track& track : of_object) {
      for (const auto& [frame, error] : track.errors) {
        const auto later = track.errors.find(frame + span);
        if (later == track.errors.end()) continue;
        measured += (later->second - error).cwiseAbs2();
        ++pairs;
      }
    }
  }
  ASSERT_GT(pairs, 200);
  measured /= pairs;

  calibration::CalibrationOptions options;
  options.frames = 400;
  const calibration::CalibrationReport report = calibration::calibrate(data, options);
  ASSERT_GT(report.objects.offset_tracks, 30);
  EXPECT_EQ(report.objects.offset_lags, span);
  const auto predicted = [&](const calibration::StereoErrorSpread& fit, int c) {
    return 2.0 * fit.offset_independent(c) * fit.offset_independent(c) +
           span * fit.offset_walk(c) * fit.offset_walk(c);
  };
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(predicted(report.objects, c), measured(c), 0.25 * measured(c)) << c;
  }
  // Fitted over the first few lags only, the walk falls short of the drift over the span.
  options.offset_max_lag = 4;
  const calibration::CalibrationReport short_lags = calibration::calibrate(data, options);
  EXPECT_EQ(short_lags.objects.offset_lags, 4);
  for (int c = 0; c < 3; ++c) {
    EXPECT_LT(predicted(short_lags.objects, c), 0.7 * measured(c)) << c;
  }
}

/// A robot driving along the world's x for `frames` frames, pitching as a sine of amplitude 0.04
/// rad and period 120 frames about a body pitched nose-down by `mount` (about its y axis).
dataset::Dataset pitching_robot(int frames, double mount) {
  dataset::Dataset data;
  data.robots.resize(1);
  dataset::RobotData& robot = data.robots.front();
  for (int k = 0; k < frames; ++k) {
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.translation() = Eigen::Vector3d(0.8 * k, 0.0, 0.0);
    pose.linear() = Eigen::AngleAxisd(0.04 * std::sin(2.0 * M_PI * k / 120.0) + mount,
                                      Eigen::Vector3d::UnitY())
                        .toRotationMatrix();
    robot.groundtruth.push_back(pose);
    if (k > 0) robot.odometry.push_back(robot.groundtruth[k - 1].inverse() * pose);
  }
  robot.objects.resize(frames);
  robot.features.resize(frames);
  return data;
}

TEST(Calibration, MeasuresTheTiltFromLevelAndHowLongItLasts) {
  // The tilt's RMS is 0.04 / sqrt(2) and its autocorrelation first drops to zero a quarter
  // period on: 480 frames hold 16 looks at it.
  const int frames = 480;
  const dataset::Dataset data = pitching_robot(frames, 0.0);
  calibration::CalibrationOptions options;
  options.frames = frames;
  const calibration::CalibrationReport report = calibration::calibrate(data, options);
  EXPECT_NEAR(report.tilt_rms, 0.04 / std::sqrt(2.0), 1e-3);
  EXPECT_NEAR(report.tilt_decorrelation_frames, 30, 2);
  EXPECT_NEAR(report.tilt_looks, frames / static_cast<double>(report.tilt_decorrelation_frames),
              1e-12);
  const double looks = report.tilt_looks;
  EXPECT_NEAR(report.level_sigma, report.tilt_rms * std::sqrt(looks / (looks - 1.0)), 1e-12);
  // It travels level: the level axis is the body's +z.
  EXPECT_LT((report.level_axis - Eigen::Vector3d::UnitZ()).norm(), 1e-3);
  // The axis it pitches about does not tilt.
  options.up_axis = "-y";
  EXPECT_LT(calibration::calibrate(data, options).tilt_rms, 1e-12);
  options.up_axis = "up";
  EXPECT_THROW(calibration::calibrate(data, options), std::invalid_argument);
}

TEST(Calibration, FindsTheLevelAxisOfAPitchedMount) {
  // The body is pitched 0.03 rad nose-down against its travel (a camera mounted so): it travels
  // along a direction 0.03 rad above its own x axis, and its level axis is +z tilted back by
  // that much. The tilt about that axis is the sine's alone, and the report suggests that axis.
  const int frames = 480;
  const double mount = 0.03;
  const dataset::Dataset data = pitching_robot(frames, mount);
  calibration::CalibrationOptions options;
  options.frames = frames;
  const calibration::CalibrationReport report = calibration::calibrate(data, options);
  const Eigen::Vector3d expected(-std::sin(mount), 0.0, std::cos(mount));
  EXPECT_LT((report.level_axis - expected).norm(), 1e-3) << report.level_axis.transpose();
  EXPECT_NEAR(report.tilt_rms, 0.04 / std::sqrt(2.0), 1e-3);
  const std::string yaml = calibration::to_yaml(report, options);
  EXPECT_NE(yaml.find("# level_up_axis: [-0.0300, 0.0000, 0.999"), std::string::npos) << yaml;
}

TEST(ConfigOverrides, SetKeysOverTheConfigAndNameBadEntries) {
  const EstimatorOptions options = config::apply_overrides(
      EstimatorOptions{}, {"odometry_rotation_sigma=0.02", "object_noise.horizontal=7",
                           "consensus.neighbour_chi2_probability=0.99"});
  EXPECT_EQ(options.odometry_rotation_sigma, 0.02);
  EXPECT_EQ(options.object_noise.horizontal, 7.0);
  EXPECT_EQ(options.object_noise.vertical, EstimatorOptions{}.object_noise.vertical);
  EXPECT_EQ(options.consensus.neighbour_chi2_probability, 0.99);
  EXPECT_THROW(config::apply_overrides({}, {"window_size"}), config::ConfigError);
  EXPECT_THROW(config::apply_overrides({}, {"window_size=1"}), config::ConfigError);
  EXPECT_THROW(config::apply_overrides({}, {"no_such_key=1"}), config::ConfigError);

  // Validated as a whole, not entry by entry: turning a detection offset off needs its sigma and
  // its walk at zero, and either order does it (the walk alone without the sigma is invalid).
  EstimatorOptions offset;
  offset.object_offset_sigma = StereoNoise::isotropic(0.5);
  offset.object_offset_walk = StereoNoise::isotropic(0.2);
  ASSERT_TRUE(offset.validate().empty());
  for (const std::vector<std::string>& order :
       {std::vector<std::string>{"object_offset_sigma=0", "object_offset_walk=0"},
        std::vector<std::string>{"object_offset_walk=0", "object_offset_sigma=0"}}) {
    const EstimatorOptions off = config::apply_overrides(offset, order);
    EXPECT_EQ(off.object_offset_sigma.horizontal, 0.0);
    EXPECT_EQ(off.object_offset_walk.horizontal, 0.0);
  }
  // A combination that is invalid at the end is refused, naming the entries and the key.
  try {
    (void)config::apply_overrides(offset, {"object_offset_sigma=0", "window_size=20"});
    ADD_FAILURE() << "a walk without a sigma was accepted";
  } catch (const config::ConfigError& error) {
    EXPECT_THAT(error.what(),
                ::testing::HasSubstr("--set object_offset_sigma=0 --set window_size=20"));
    EXPECT_THAT(error.what(), ::testing::HasSubstr("object_offset_walk"));
  }
}

/// How far the start pose (the window's oldest pose, frame 0) and the newest pose move when a
/// neighbour's marginal of the one object says it is 5 cm to the side, for a robot that has seen
/// it for 10 frames from a start of the given uncertainty (metres and radians; 0: the options'
/// default).
struct ConsensusMoves {
  double start = 0.0;           ///< metres
  double start_rotation = 0.0;  ///< radians
  double newest = 0.0;          ///< metres
};
ConsensusMoves consensus_moves(double initial_sigma) {
  const StereoCamera camera = testing::kitti_like_camera();
  EstimatorOptions options;
  options.use_point_features = false;
  options.odometry_translation_sigma = 0.01;
  options.odometry_rotation_sigma = 0.001;
  options.object_min_distance = 1.0;
  options.object_max_distance = 100.0;
  if (initial_sigma > 0.0) {
    options.initial_position_sigma = initial_sigma;
    options.initial_rotation_sigma = initial_sigma;
  }
  const Eigen::Vector3d p_object(26.0, 4.0, 0.5);
  Estimator estimator(options, camera, Eigen::Isometry3d::Identity());
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d step = Eigen::Isometry3d::Identity();
  step.translation() = Eigen::Vector3d(0.5, 0.0, 0.0);
  for (int frame = 0; frame < 10; ++frame) {
    FrameInput input = testing::straight_drive_frame(frame, step, pose);
    input.objects.push_back(
        {7, camera.denormalize(UpdaterHelper::project(camera, pose, p_object)->xy)});
    estimator.process(input);
  }
  EXPECT_EQ(estimator.state().poses.front().frame, 0);
  const std::vector<ObjectEstimate> objects = estimator.objects();
  EXPECT_EQ(objects.size(), 1u);
  if (objects.size() != 1) return {};
  const Eigen::Isometry3d start = estimator.state().poses.front().T_world_body;
  const Eigen::Isometry3d newest = estimator.current_pose();
  WeightedMarginal neighbour;
  neighbour.weight = 0.5;
  neighbour.marginal =
      Marginal({7}, objects[0].p_world + Eigen::Vector3d(0.0, 0.05, 0.0), objects[0].covariance);
  estimator.fuse({neighbour});
  const Eigen::Isometry3d start_after = estimator.state().poses.front().T_world_body;
  return {(start_after.translation() - start.translation()).norm(),
          Eigen::AngleAxisd(start.linear().transpose() * start_after.linear()).angle(),
          (estimator.current_pose().translation() - newest.translation()).norm()};
}

TEST(StartPose, AGivenStartIsExactByDefaultSoConsensusMovesTheDriftNotTheFrame) {
  // By default the start the filter is given defines its frame: the neighbour's object moves the
  // robot's drifted newest pose, and not its start.
  const ConsensusMoves exact = consensus_moves(0.0);
  EXPECT_LT(exact.start, 1e-5);
  EXPECT_LT(exact.start_rotation, 1e-5);
  EXPECT_GT(exact.newest, 1e-3);
  // With an uncertain start (1 mm, 1 mrad: a surveyed start) the same step moves the whole frame,
  // the start included, as the prior allows.
  const ConsensusMoves uncertain = consensus_moves(1e-3);
  EXPECT_GT(uncertain.start_rotation, 1e-4);
}

}  // namespace
}  // namespace concord
