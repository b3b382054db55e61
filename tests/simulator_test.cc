#include "sim/simulator.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <map>
#include <numbers>
#include <set>
#include <stdexcept>
#include <string>

#include "concord/estimator/lie.h"

namespace concord::sim {
namespace {

using ::testing::HasSubstr;

/// A small team that simulates in a few milliseconds.
SimulationOptions small_options() {
  SimulationOptions options;
  options.robots = 3;
  options.frames = 120;
  options.objects = 40;
  options.points_per_frame = 15;
  options.seed = 7;
  return options;
}

SimulationOptions noiseless(SimulationOptions options) {
  options.odometry_translation_noise = 0.0;
  options.odometry_rotation_noise = 0.0;
  options.pixel_noise = 0.0;
  return options;
}

bool same_poses(const std::vector<Eigen::Isometry3d>& a, const std::vector<Eigen::Isometry3d>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (a[i].matrix() != b[i].matrix()) return false;
  }
  return true;
}

bool same_observations(const std::vector<std::vector<StereoObservation>>& a,
                       const std::vector<std::vector<StereoObservation>>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t k = 0; k < a.size(); ++k) {
    if (a[k].size() != b[k].size()) return false;
    for (std::size_t i = 0; i < a[k].size(); ++i) {
      if (a[k][i].id != b[k][i].id || a[k][i].uv != b[k][i].uv) return false;
    }
  }
  return true;
}

bool same_robot(const dataset::RobotData& a, const dataset::RobotData& b) {
  return a.index == b.index && a.has_features == b.has_features &&
         same_poses(a.groundtruth, b.groundtruth) && same_poses(a.odometry, b.odometry) &&
         same_observations(a.objects, b.objects) && same_observations(a.features, b.features);
}

/// Bit-for-bit equality of everything a dataset holds (but its root folder).
bool same_dataset(const dataset::Dataset& a, const dataset::Dataset& b) {
  if (a.name != b.name || a.robots.size() != b.robots.size()) return false;
  if (a.camera.K != b.camera.K || a.camera.T_cam0_body.matrix() != b.camera.T_cam0_body.matrix() ||
      a.camera.T_cam0_cam1.matrix() != b.camera.T_cam0_cam1.matrix()) {
    return false;
  }
  if (a.objects_groundtruth != b.objects_groundtruth) return false;
  for (std::size_t i = 0; i < a.robots.size(); ++i) {
    if (!same_robot(a.robots[i], b.robots[i])) return false;
  }
  return true;
}

/// The visibility rule of docs/simulator.md, written out independently of the simulator: in
/// front of both cameras, inside both fields of view, left depth in [min_depth, max_depth].
/// Returns the noiseless normalized coordinates when visible.
std::optional<Eigen::Vector4d> visible_projection(const SimulationOptions& options,
                                                  const StereoCamera& camera,
                                                  const Eigen::Isometry3d& T_world_body,
                                                  const Eigen::Vector3d& p_world) {
  const Eigen::Vector3d p_body = T_world_body.inverse() * p_world;
  const Eigen::Vector3d left = camera.T_cam0_body * p_body;
  const Eigen::Vector3d right = camera.T_cam1_body() * p_body;
  if (left.z() < options.min_depth || left.z() > options.max_depth || right.z() <= 0.0) {
    return std::nullopt;
  }
  const double degrees = std::numbers::pi / 180.0;
  const double tan_h = std::tan(0.5 * options.horizontal_fov_degrees * degrees);
  const double tan_v = std::tan(0.5 * options.vertical_fov_degrees * degrees);
  const Eigen::Vector4d xy(left.x() / left.z(), left.y() / left.z(), right.x() / right.z(),
                           right.y() / right.z());
  if (std::abs(xy(0)) > tan_h || std::abs(xy(2)) > tan_h || std::abs(xy(1)) > tan_v ||
      std::abs(xy(3)) > tan_v) {
    return std::nullopt;
  }
  return xy;
}

/// The left-camera point of a noiseless rectified stereo observation (K = identity).
Eigen::Vector3d triangulate_left(const Eigen::Vector4d& xy, double baseline) {
  const double depth = baseline / (xy(0) - xy(2));
  return depth * Eigen::Vector3d(xy(0), xy(1), 1.0);
}

TEST(SimulatorTest, SameSeedGivesTheSameDatasetAndAnotherSeedAnotherOne) {
  const SimulationOptions options = small_options();
  const dataset::Dataset first = simulate(options);
  EXPECT_TRUE(same_dataset(first, simulate(options)));

  SimulationOptions other = options;
  other.seed = options.seed + 1;
  const dataset::Dataset second = simulate(other);
  for (std::size_t i = 0; i < first.robots.size(); ++i) {
    EXPECT_FALSE(same_poses(first.robots[i].groundtruth, second.robots[i].groundtruth)) << i;
    EXPECT_FALSE(same_poses(first.robots[i].odometry, second.robots[i].odometry)) << i;
    EXPECT_FALSE(same_observations(first.robots[i].features, second.robots[i].features)) << i;
  }
  EXPECT_NE(first.objects_groundtruth, second.objects_groundtruth);
}

TEST(SimulatorTest, RobotPathOdometryAndFeaturesDoNotDependOnTeamSize) {
  SimulationOptions two = small_options();
  two.robots = 2;
  SimulationOptions five = two;
  five.robots = 5;
  const dataset::Dataset small_team = simulate(two);
  const dataset::Dataset large_team = simulate(five);
  for (int i = 0; i < 2; ++i) {
    const auto& a = small_team.robots[i];
    const auto& b = large_team.robots[i];
    EXPECT_TRUE(same_poses(a.groundtruth, b.groundtruth)) << i;
    EXPECT_TRUE(same_poses(a.odometry, b.odometry)) << i;
    EXPECT_TRUE(same_observations(a.features, b.features)) << i;
  }
}

TEST(SimulatorTest, DatasetHasTheSharedLayoutConventions) {
  const SimulationOptions options = small_options();
  const dataset::Dataset data = simulate(options);
  EXPECT_EQ(data.name, "sim");
  EXPECT_TRUE(data.camera.K.isIdentity(0.0));
  EXPECT_DOUBLE_EQ(data.camera.baseline(), options.baseline);
  // Optical z (forward) is body y, optical y (down) is -body z.
  EXPECT_TRUE(data.camera.T_cam0_body.linear().row(2).isApprox(Eigen::RowVector3d(0, 1, 0)));
  EXPECT_TRUE(data.camera.T_cam0_body.linear().row(1).isApprox(Eigen::RowVector3d(0, 0, -1)));
  ASSERT_EQ(static_cast<int>(data.robots.size()), options.robots);
  ASSERT_EQ(static_cast<int>(data.objects_groundtruth.size()), options.objects);
  for (int id = 0; id < options.objects; ++id) EXPECT_TRUE(data.objects_groundtruth.contains(id));
  for (std::size_t i = 0; i < data.robots.size(); ++i) {
    const auto& robot = data.robots[i];
    EXPECT_EQ(robot.index, static_cast<int>(i));
    EXPECT_EQ(robot.num_frames(), options.frames);
    EXPECT_EQ(static_cast<int>(robot.odometry.size()), options.frames - 1);
    EXPECT_EQ(static_cast<int>(robot.objects.size()), options.frames);
    EXPECT_EQ(static_cast<int>(robot.features.size()), options.frames);
    EXPECT_TRUE(robot.has_features);
  }
  SimulationOptions without_points = options;
  without_points.points_per_frame = 0;
  for (const auto& robot : simulate(without_points).robots) {
    EXPECT_FALSE(robot.has_features);
    for (const auto& frame : robot.features) EXPECT_TRUE(frame.empty());
  }
}

TEST(SimulatorTest, BodyFacesAlongThePathWithZUp) {
  const dataset::Dataset data = simulate(small_options());
  for (const auto& robot : data.robots) {
    for (int k = 0; k + 1 < robot.num_frames(); ++k) {
      const Eigen::Matrix3d R = robot.groundtruth[k].linear();
      EXPECT_NEAR((R.transpose() * R - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-12);
      EXPECT_NEAR(R.determinant(), 1.0, 1e-12);
      const Eigen::Vector3d step =
          robot.groundtruth[k + 1].translation() - robot.groundtruth[k].translation();
      // Forward (body y) along the motion, right (body x) horizontal.
      EXPECT_GT(step.normalized().dot(R.col(1)), 0.99) << "robot " << robot.index << " frame " << k;
      EXPECT_NEAR(R.col(0).z(), 0.0, 1e-12);
      EXPECT_GT(R.col(2).z(), 0.9);
    }
  }
}

TEST(SimulatorTest, ObjectsAreObservedExactlyWhenVisibleAndReprojectWithoutNoise) {
  SimulationOptions options = noiseless(small_options());
  options.period_frames = options.frames;  // one whole lap
  const dataset::Dataset data = simulate(options);
  std::map<LandmarkId, std::set<int>> observers;
  long long observations = 0;
  for (const auto& robot : data.robots) {
    for (int k = 0; k < robot.num_frames(); ++k) {
      std::map<LandmarkId, Eigen::Vector4d> expected;
      for (const auto& [id, p_world] : data.objects_groundtruth) {
        if (const auto xy =
                visible_projection(options, data.camera, robot.groundtruth[k], p_world)) {
          expected[id] = *xy;
        }
      }
      std::map<LandmarkId, Eigen::Vector4d> observed;
      for (const auto& observation : robot.objects[k]) {
        EXPECT_TRUE(observed.emplace(observation.id, observation.uv).second)
            << "object " << observation.id << " twice in frame " << k;
        observers[observation.id].insert(robot.index);
      }
      ASSERT_EQ(observed.size(), expected.size()) << "robot " << robot.index << " frame " << k;
      for (const auto& [id, xy] : expected) {
        ASSERT_TRUE(observed.contains(id)) << "visible object " << id << " not observed";
        EXPECT_LT((observed[id] - xy).cwiseAbs().maxCoeff(), 1e-12) << "object " << id;
      }
      observations += static_cast<long long>(observed.size());
    }
  }
  EXPECT_GT(observations, 0);
  // Objects are placed in view of a robot, and paths overlap: every object is seen, and over a
  // lap most are seen by more than one robot.
  EXPECT_EQ(static_cast<int>(observers.size()), options.objects);
  int common = 0;
  for (const auto& [id, robots] : observers) common += robots.size() > 1 ? 1 : 0;
  EXPECT_GT(common, 3 * options.objects / 4);
}

TEST(SimulatorTest, FeaturesAreVisibleStaticPointsThatReprojectWithoutNoise) {
  const SimulationOptions options = noiseless(small_options());
  const dataset::Dataset data = simulate(options);
  long long checked = 0;
  for (const auto& robot : data.robots) {
    std::map<LandmarkId, Eigen::Vector3d> first_position;
    for (int k = 0; k < robot.num_frames(); ++k) {
      for (const auto& observation : robot.features[k]) {
        const Eigen::Vector3d p_cam0 = triangulate_left(observation.uv, options.baseline);
        const Eigen::Vector3d p_world =
            robot.groundtruth[k] * (data.camera.T_cam0_body.inverse() * p_cam0);
        // The rule holds and the stereo pair is exact (same row, disparity of the baseline).
        const auto xy = visible_projection(options, data.camera, robot.groundtruth[k], p_world);
        ASSERT_TRUE(xy.has_value()) << "robot " << robot.index << " frame " << k;
        EXPECT_LT((*xy - observation.uv).cwiseAbs().maxCoeff(), 1e-9);
        EXPECT_NEAR(observation.uv(1), observation.uv(3), 1e-12);
        // The same world point over the whole track.
        const auto [entry, inserted] = first_position.emplace(observation.id, p_world);
        if (!inserted) {
          EXPECT_LT((entry->second - p_world).norm(), 1e-8) << observation.id;
        }
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 1000);
}

TEST(SimulatorTest, NoisyObservationsStayWithinTheRulesOfTheirTruePoint) {
  // With noise, objects are still observed exactly when their true position is visible.
  const SimulationOptions options = small_options();
  const dataset::Dataset data = simulate(options);
  for (const auto& robot : data.robots) {
    for (int k = 0; k < robot.num_frames(); ++k) {
      for (const auto& observation : robot.objects[k]) {
        const auto xy = visible_projection(options, data.camera, robot.groundtruth[k],
                                           data.objects_groundtruth.at(observation.id));
        ASSERT_TRUE(xy.has_value());
        EXPECT_LT((*xy - observation.uv).cwiseAbs().maxCoeff(), 8.0 * options.pixel_noise);
      }
    }
  }
}

TEST(SimulatorTest, NoiselessOdometryComposesToGroundTruth) {
  const dataset::Dataset data = simulate(noiseless(small_options()));
  for (const auto& robot : data.robots) {
    Eigen::Isometry3d T_world_body = robot.groundtruth.front();
    for (int k = 1; k < robot.num_frames(); ++k) {
      T_world_body = T_world_body * robot.odometry[k - 1];
      EXPECT_LT((T_world_body.matrix() - robot.groundtruth[k].matrix()).cwiseAbs().maxCoeff(), 1e-9)
          << "robot " << robot.index << " frame " << k;
    }
  }
}

TEST(SimulatorTest, NoiseHasTheConfiguredStandardDeviations) {
  SimulationOptions options = small_options();
  options.robots = 1;
  options.frames = 3000;
  options.objects = 0;
  options.points_per_frame = 10;
  options.odometry_translation_noise = 0.02;
  options.odometry_rotation_noise = 0.005;
  options.pixel_noise = 0.003;
  const dataset::Dataset data = simulate(options);
  const auto& robot = data.robots[0];

  // Odometry: log(T_true^-1 T_measured) per axis.
  Eigen::Matrix<double, 6, 1> sum = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Matrix<double, 6, 1> sum_squares = sum;
  for (int k = 1; k < robot.num_frames(); ++k) {
    const Eigen::Isometry3d truth = robot.groundtruth[k - 1].inverse() * robot.groundtruth[k];
    const lie::Vector6d xi = lie::se3_log(truth.inverse() * robot.odometry[k - 1]);
    sum += xi;
    sum_squares += xi.cwiseProduct(xi);
  }
  const double n = robot.num_frames() - 1;
  for (int axis = 0; axis < 6; ++axis) {
    const double sigma =
        axis < 3 ? options.odometry_translation_noise : options.odometry_rotation_noise;
    EXPECT_NEAR(sum(axis) / n, 0.0, 4.0 * sigma / std::sqrt(n)) << "axis " << axis;
    EXPECT_NEAR(std::sqrt(sum_squares(axis) / n), sigma, 0.05 * sigma) << "axis " << axis;
  }

  // Features: the vertical coordinates of a noiseless rectified pair are equal, so
  // v_left - v_right has twice the variance of one coordinate.
  double squares = 0.0;
  long long count = 0;
  for (const auto& frame : robot.features) {
    for (const auto& observation : frame) {
      const double difference = observation.uv(1) - observation.uv(3);
      squares += difference * difference;
      ++count;
    }
  }
  ASSERT_GT(count, 10000);
  EXPECT_NEAR(std::sqrt(squares / (2.0 * count)), options.pixel_noise, 0.03 * options.pixel_noise);
}

// --object-noise: the object observations carry their own noise, the point features keep
// --pixel-noise (a detector's box centres against tracked corners).
TEST(SimulatorTest, ObjectObservationsHaveTheirOwnNoiseWhenGiven) {
  SimulationOptions options = small_options();
  options.robots = 1;
  options.frames = 2000;
  options.points_per_frame = 10;
  options.pixel_noise = 0.002;
  options.object_noise = 0.008;
  const dataset::Dataset data = simulate(options);
  // The vertical coordinates of a noiseless rectified pair are equal: v_left - v_right has
  // twice the variance of one coordinate.
  const auto spread = [](const auto& frames) {
    double squares = 0.0;
    long long count = 0;
    for (const auto& frame : frames) {
      for (const auto& observation : frame) {
        const double difference = observation.uv(1) - observation.uv(3);
        squares += difference * difference;
        ++count;
      }
    }
    EXPECT_GT(count, 5000);
    return std::sqrt(squares / (2.0 * static_cast<double>(count)));
  };
  EXPECT_NEAR(spread(data.robots[0].objects), 0.008, 0.05 * 0.008);
  EXPECT_NEAR(spread(data.robots[0].features), 0.002, 0.05 * 0.002);
  // Unset, objects take the pixel noise.
  options.object_noise.reset();
  EXPECT_NEAR(spread(simulate(options).robots[0].objects), 0.002, 0.05 * 0.002);
}

TEST(SimulatorTest, TrackIdsArePrivateToARobotAndNeverReusedAfterAGap) {
  SimulationOptions options = small_options();
  options.point_track_loss = 0.1;
  const dataset::Dataset data = simulate(options);
  for (const auto& robot : data.robots) {
    std::map<LandmarkId, int> last_frame;
    for (int k = 0; k < robot.num_frames(); ++k) {
      std::set<LandmarkId> in_frame;
      for (const auto& observation : robot.features[k]) {
        EXPECT_TRUE(in_frame.insert(observation.id).second) << "id twice in frame " << k;
        const auto [entry, inserted] = last_frame.emplace(observation.id, k);
        if (!inserted) {
          EXPECT_EQ(entry->second, k - 1)
              << "robot " << robot.index << " track " << observation.id << " resumes after a gap";
          entry->second = k;
        }
      }
    }
  }
}

TEST(SimulatorTest, AboutPointsPerFrameAreVisibleOnTracksOfSeveralFrames) {
  SimulationOptions options = small_options();
  options.points_per_frame = 30;
  options.point_track_loss = 0.0;
  const SimulationSummary summary = summarize(simulate(options));
  EXPECT_EQ(summary.robots, options.robots);
  EXPECT_EQ(summary.frames, static_cast<long long>(options.robots) * options.frames);
  EXPECT_GE(summary.features_per_frame, 0.95 * options.points_per_frame);
  EXPECT_LE(summary.features_per_frame, options.points_per_frame);
  EXPECT_GT(summary.mean_track_length, 5.0);

  options.point_track_loss = 0.2;
  const SimulationSummary lossy = summarize(simulate(options));
  EXPECT_GE(lossy.features_per_frame, 0.95 * options.points_per_frame);
  EXPECT_LT(lossy.mean_track_length, summary.mean_track_length);
  EXPECT_GT(lossy.mean_track_length, 2.0);
}

TEST(SimulatorTest, ValidationNamesEveryBadParameter) {
  EXPECT_TRUE(SimulationOptions{}.validate().empty());
  EXPECT_TRUE(small_options().validate().empty());

  struct Case {
    std::string flag;
    void (*spoil)(SimulationOptions&);
  };
  const std::vector<Case> cases = {
      {"--robots", [](SimulationOptions& o) { o.robots = 0; }},
      {"--frames", [](SimulationOptions& o) { o.frames = 0; }},
      {"--objects", [](SimulationOptions& o) { o.objects = -1; }},
      {"--points-per-frame", [](SimulationOptions& o) { o.points_per_frame = -5; }},
      {"--odometry-translation-noise",
       [](SimulationOptions& o) { o.odometry_translation_noise = -0.1; }},
      {"--odometry-rotation-noise",
       [](SimulationOptions& o) { o.odometry_rotation_noise = std::nan(""); }},
      {"--pixel-noise", [](SimulationOptions& o) { o.pixel_noise = -1.0; }},
      {"--object-noise", [](SimulationOptions& o) { o.object_noise = -0.01; }},
      {"--point-track-loss", [](SimulationOptions& o) { o.point_track_loss = 1.0; }},
      {"--baseline", [](SimulationOptions& o) { o.baseline = 0.0; }},
      {"--horizontal-fov", [](SimulationOptions& o) { o.horizontal_fov_degrees = 180.0; }},
      {"--vertical-fov", [](SimulationOptions& o) { o.vertical_fov_degrees = 0.0; }},
      {"--min-depth", [](SimulationOptions& o) { o.min_depth = -1.0; }},
      {"--max-depth", [](SimulationOptions& o) { o.max_depth = 0.4; }},
      {"--period", [](SimulationOptions& o) { o.period_frames = 1; }},
      {"--amplitude-x", [](SimulationOptions& o) { o.amplitude_x = 0.0; }},
      {"--amplitude-y", [](SimulationOptions& o) { o.amplitude_y = INFINITY; }},
      {"--amplitude-z", [](SimulationOptions& o) { o.amplitude_z = -1.0; }},
      {"--frequency-x", [](SimulationOptions& o) { o.frequency_x = 0; }},
      {"--frequency-y", [](SimulationOptions& o) { o.frequency_y = 3; }},  // 1 and 3: both odd
      {"--centre-offset", [](SimulationOptions& o) { o.centre_offset = -2.0; }},
      {"--scale-spread", [](SimulationOptions& o) { o.scale_spread = 1.0; }},
      {"--object-min-depth", [](SimulationOptions& o) { o.object_min_depth = 0.1; }},
      {"--object-max-depth", [](SimulationOptions& o) { o.object_max_depth = 1.0; }},
      {"--object-max-depth", [](SimulationOptions& o) { o.object_max_depth = 12.0; }},
  };
  for (const auto& test_case : cases) {
    SimulationOptions options = small_options();
    test_case.spoil(options);
    const auto problems = options.validate();
    ASSERT_FALSE(problems.empty()) << test_case.flag;
    EXPECT_THAT(problems.front(), HasSubstr(test_case.flag + " = ")) << test_case.flag;
    try {
      simulate(options);
      ADD_FAILURE() << test_case.flag << ": simulate accepted invalid options";
    } catch (const std::invalid_argument& error) {
      EXPECT_THAT(error.what(), HasSubstr(test_case.flag)) << test_case.flag;
    }
  }
  // 2 and 6 reduce to 1 and 3 (both odd); 2 and 4 to 1 and 2 (a figure eight).
  SimulationOptions options = small_options();
  options.frequency_x = 2;
  options.frequency_y = 6;
  EXPECT_FALSE(options.validate().empty());
  options.frequency_y = 4;
  EXPECT_TRUE(options.validate().empty());
}

TEST(SimulatorTest, WrittenDatasetReadsBackBitForBit) {
  SimulationOptions options = small_options();
  options.frames = 30;
  const dataset::Dataset data = simulate(options);
  const std::filesystem::path folder =
      std::filesystem::path(::testing::TempDir()) /
      ("concord_simulator_round_trip_" + std::to_string(::getpid()));
  std::filesystem::remove_all(folder);
  dataset::write_dataset(data, folder);
  const dataset::Dataset read = dataset::read_dataset(folder);
  std::filesystem::remove_all(folder);
  EXPECT_TRUE(same_dataset(data, read));
}

TEST(SimulatorTest, OptionsJsonNamesEveryParameter) {
  const std::string json = to_json(small_options());
  for (const char* key : {"\"robots\": 3", "\"frames\": 120", "\"seed\": 7", "\"pixel_noise\"",
                          "\"point_track_loss\"", "\"object_max_depth\""}) {
    EXPECT_THAT(json, HasSubstr(key));
  }
}

}  // namespace
}  // namespace concord::sim
