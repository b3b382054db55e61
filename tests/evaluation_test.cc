// Evaluation metrics (paper Tables I-III) and the top-view plot, on hand-computed cases.

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <numbers>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <stdexcept>
#include <string>

#include "concord/estimator/lie.h"
#include "evaluation/metrics.h"
#include "evaluation/plot.h"

namespace concord::evaluation {
namespace {

Eigen::Isometry3d pose(double yaw, const Eigen::Vector3d& translation) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = translation;
  return T;
}

/// A wiggly ground truth with integer translations, and the exact motions between its poses.
RobotTruth wiggly_truth(int frames) {
  RobotTruth truth;
  for (int k = 0; k < frames; ++k) {
    truth.groundtruth.push_back(
        pose(0.3 * k, Eigen::Vector3d(2.0 * k, static_cast<double>(k % 3), -1.0 * k)));
  }
  for (int k = 1; k < frames; ++k) {
    truth.odometry.push_back(truth.groundtruth[k - 1].inverse() * truth.groundtruth[k]);
  }
  return truth;
}

ObjectEstimate object(LandmarkId id, const Eigen::Vector3d& p_world) {
  ObjectEstimate estimate;
  estimate.id = id;
  estimate.p_world = p_world;
  return estimate;
}

/// A team whose estimated trajectories equal the ground truth.
struct Team {
  std::vector<RobotTruth> truths;
  std::vector<RobotResult> results;
};

Team perfect_trajectories(int robots, int frames) {
  Team team;
  for (int robot = 0; robot < robots; ++robot) {
    team.truths.push_back(wiggly_truth(frames));
    team.results.push_back({team.truths.back().groundtruth, {}, {}});
  }
  return team;
}

TEST(EvaluationTest, ConstantOffsetGivesTrajectoryRmseOfItsLength) {
  Team team = perfect_trajectories(1, 10);
  for (Eigen::Isometry3d& T_world_body : team.results[0].trajectory) {
    T_world_body.translation() += Eigen::Vector3d(3.0, 4.0, 0.0);
  }
  const TeamMetrics metrics = evaluate(team.truths, team.results, {});
  ASSERT_EQ(metrics.robots.size(), 1u);
  EXPECT_DOUBLE_EQ(metrics.robots[0].trajectory_rmse, 5.0);
  EXPECT_EQ(metrics.robots[0].frames, 10);
  EXPECT_EQ(metrics.robots[0].robot, 0);
}

TEST(EvaluationTest, TeamRigidFitRemovesAnErrorOfTheWholeTeamsFrame) {
  // Every robot's estimate is the truth seen from a frame rotated by 5 degrees and shifted: the
  // trajectories are wrong by metres, their shape and the robots' relative poses are right.
  Team team = perfect_trajectories(2, 12);
  Eigen::Isometry3d frame_error = Eigen::Isometry3d::Identity();
  frame_error.linear() =
      Eigen::AngleAxisd(5.0 * std::numbers::pi / 180.0, Eigen::Vector3d(1, 2, 3).normalized())
          .toRotationMatrix();
  frame_error.translation() = Eigen::Vector3d(1.0, -2.0, 2.0);
  for (RobotResult& result : team.results) {
    for (Eigen::Isometry3d& T_world_body : result.trajectory) T_world_body = frame_error * T_world_body;
  }
  // Robot 0's object is seen from the same wrong frame and 0.5 m off besides; robot 1 has none.
  const Eigen::Vector3d object_truth(4.0, 1.0, -2.0);
  team.results[0].objects = {object(7, frame_error * (object_truth + Eigen::Vector3d(0, 0.5, 0)))};
  const TeamMetrics metrics = evaluate(team.truths, team.results, {{7, object_truth}});
  EXPECT_GT(metrics.robots[1].trajectory_rmse, 1.0);
  EXPECT_GT(metrics.robots[0].object_error, 1.0);
  EXPECT_NEAR(metrics.team_aligned.object_error, 0.5, 1e-9);
  EXPECT_LT(metrics.team_aligned.trajectory_rmse, 1e-9);
  EXPECT_NEAR(metrics.team_aligned.rotation_degrees, 5.0, 1e-9);
  // The fit maps the estimate onto the truth: the inverse of frame_error.
  EXPECT_NEAR(metrics.team_aligned.translation, frame_error.inverse().translation().norm(), 1e-9);
  EXPECT_EQ(metrics.team_aligned.robots, 2);
  EXPECT_EQ(metrics.team_aligned.poses, 24);
  EXPECT_NE(format_table(metrics, "t").find("one rigid fit of the 2 robots"), std::string::npos);
}

TEST(EvaluationTest, TeamRigidFitKeepsTheRobotsErrorsRelativeToEachOther) {
  // Robot 1 is 2 m off, robot 0 exact, both on the same path: the best single transform moves
  // both by half the offset (their centred paths are alike, so it does not rotate), and each
  // robot is left 1 m off.
  Team team = perfect_trajectories(2, 12);
  for (Eigen::Isometry3d& T_world_body : team.results[1].trajectory) {
    T_world_body.translation() += Eigen::Vector3d(0.0, 2.0, 0.0);
  }
  const TeamMetrics metrics = evaluate(team.truths, team.results, {});
  EXPECT_NEAR(metrics.team_aligned.trajectory_rmse, 1.0, 1e-9);
  EXPECT_NEAR(metrics.team_aligned.rotation_degrees, 0.0, 1e-6);
  EXPECT_NEAR(metrics.team_aligned.translation, 1.0, 1e-9);
}

TEST(EvaluationTest, TeamRigidFitTakesOnlyRobotsInRobotZerosFrameFromTheirFirstFrames) {
  Team team = perfect_trajectories(3, 10);
  // Robot 1 ends in its own start frame (never joined robot 0's): left out, however wrong.
  team.results[1].trajectory_frames.assign(10, 1);
  for (Eigen::Isometry3d& T : team.results[1].trajectory) T.translation().x() += 50.0;
  // Robot 2 joined at frame 4: its poses before are in another frame and left out.
  team.results[2].aligned_at_frame = 4;
  team.results[2].trajectory_frames.assign(10, std::nullopt);
  for (int k = 0; k < 4; ++k) {
    team.results[2].trajectory_frames[static_cast<std::size_t>(k)] = 2;
    team.results[2].trajectory[static_cast<std::size_t>(k)].translation().y() += 50.0;
  }
  const TeamMetrics metrics = evaluate(team.truths, team.results, {});
  EXPECT_EQ(metrics.team_aligned.robots, 2);
  EXPECT_EQ(metrics.team_aligned.poses, 10 + 6);
  EXPECT_LT(metrics.team_aligned.trajectory_rmse, 1e-9);
  // Too few poses: nothing to fit.
  Team tiny = perfect_trajectories(1, 2);
  EXPECT_TRUE(std::isnan(evaluate(tiny.truths, tiny.results, {}).team_aligned.trajectory_rmse));
}

TEST(EvaluationTest, AlignmentNeesIsTheLeftErrorOfTTeamOwnUnderItsCovariance) {
  Team team = perfect_trajectories(2, 5);  // both start at the identity: T_team_own's truth
  RobotResult& moved = team.results[1];
  moved.trajectory_frames.assign(5, 0);
  moved.moved = true;
  lie::Vector6d error;
  error << 0.1, 0.2, 0.3, 0.01, 0.02, 0.03;
  moved.T_team_own = lie::se3_exp(-error);  // the truth is exp(error) T_team_own
  moved.T_team_own_covariance.diagonal() << 0.01, 0.04, 0.09, 1e-4, 4e-4, 9e-4;
  const TeamMetrics metrics = evaluate(team.truths, team.results, {});
  EXPECT_NEAR(metrics.robots[1].alignment_nees, 6.0, 1e-9);
  EXPECT_TRUE(std::isnan(metrics.robots[0].alignment_nees));  // did not move
  moved.T_team_own_covariance.setZero();  // not known
  EXPECT_TRUE(std::isnan(evaluate(team.truths, team.results, {}).robots[1].alignment_nees));
}

TEST(EvaluationTest, TranslationRmseIsTheRootOfTheMeanSquare) {
  // Errors of 1 and 7 m: sqrt((1 + 49) / 2) = 5.
  const std::vector<Eigen::Isometry3d> groundtruth = {pose(0.0, Eigen::Vector3d::Zero()),
                                                      pose(1.0, Eigen::Vector3d(1, 1, 1))};
  const std::vector<Eigen::Isometry3d> estimate = {pose(0.5, Eigen::Vector3d(1, 0, 0)),
                                                   pose(1.0, Eigen::Vector3d(1, 1, 8))};
  EXPECT_DOUBLE_EQ(translation_rmse(estimate, groundtruth), 5.0);
  EXPECT_TRUE(std::isnan(translation_rmse({}, {})));
}

TEST(EvaluationTest, DeadReckoningComposesOnTheRight) {
  // Two steps of "1 m forward, then turn left 90 degrees" from the origin end at (1, 1).
  const Eigen::Isometry3d step = pose(M_PI / 2.0, Eigen::Vector3d(1.0, 0.0, 0.0));
  const std::vector<Eigen::Isometry3d> trajectory =
      dead_reckoning(Eigen::Isometry3d::Identity(), {step, step});
  ASSERT_EQ(trajectory.size(), 3u);
  EXPECT_TRUE(trajectory[0].isApprox(Eigen::Isometry3d::Identity()));
  EXPECT_TRUE(trajectory[2].translation().isApprox(Eigen::Vector3d(1.0, 1.0, 0.0)));
}

TEST(EvaluationTest, DeadReckoningOfExactMotionReproducesGroundTruth) {
  const Team team = perfect_trajectories(1, 25);
  const RobotTruth& truth = team.truths[0];
  const std::vector<Eigen::Isometry3d> trajectory =
      dead_reckoning(truth.groundtruth.front(), truth.odometry);
  ASSERT_EQ(trajectory.size(), truth.groundtruth.size());
  for (std::size_t k = 0; k < trajectory.size(); ++k) {
    EXPECT_TRUE(trajectory[k].isApprox(truth.groundtruth[k], 1e-12)) << "frame " << k;
  }
  const TeamMetrics metrics = evaluate(team.truths, team.results, {});
  EXPECT_NEAR(metrics.robots[0].odometry_rmse, 0.0, 1e-9);
  EXPECT_NEAR(metrics.robots[0].trajectory_rmse, 0.0, 1e-12);
}

TEST(EvaluationTest, EmptyOdometryLeavesOdometryRmseUnknown) {
  Team team = perfect_trajectories(1, 5);
  team.truths[0].odometry.clear();
  const TeamMetrics metrics = evaluate(team.truths, team.results, {});
  EXPECT_TRUE(std::isnan(metrics.robots[0].odometry_rmse));
}

TEST(EvaluationTest, ObjectErrorAveragesDistancesToGroundTruth) {
  Team team = perfect_trajectories(1, 3);
  const std::map<LandmarkId, Eigen::Vector3d> objects_groundtruth = {{1, Eigen::Vector3d(10, 0, 0)},
                                                                     {2, Eigen::Vector3d(0, 20, 0)},
                                                                     {3, Eigen::Vector3d(5, 5, 5)}};
  team.results[0].objects = {
      object(1, Eigen::Vector3d(11, 0, 0)),  // 1 m off
      object(2, Eigen::Vector3d(0, 20, 3)),  // 3 m off
      object(99, Eigen::Vector3d(0, 0, 0)),  // no ground truth: not evaluated
  };
  const TeamMetrics metrics = evaluate(team.truths, team.results, objects_groundtruth);
  EXPECT_DOUBLE_EQ(metrics.robots[0].object_error, 2.0);
  EXPECT_EQ(metrics.robots[0].objects_evaluated, 2);
}

TEST(EvaluationTest, DisagreementCountsOnlyRobotsHoldingTheObject) {
  Team team = perfect_trajectories(3, 3);
  team.results[0].objects = {object(7, Eigen::Vector3d(0, 0, 0)),
                             object(8, Eigen::Vector3d(1, 1, 1))};
  team.results[1].objects = {object(7, Eigen::Vector3d(3, 4, 0))};
  team.results[2].objects = {object(9, Eigen::Vector3d(2, 2, 2))};
  const TeamMetrics metrics = evaluate(team.truths, team.results, {});
  EXPECT_DOUBLE_EQ(metrics.robots[0].disagreement, 5.0);
  EXPECT_EQ(metrics.robots[0].disagreement_pairs, 1);
  EXPECT_DOUBLE_EQ(metrics.robots[1].disagreement, 5.0);
  EXPECT_EQ(metrics.robots[1].disagreement_pairs, 1);
  EXPECT_TRUE(std::isnan(metrics.robots[2].disagreement));
  EXPECT_EQ(metrics.robots[2].disagreement_pairs, 0);
}

TEST(EvaluationTest, DisagreementAveragesOverEveryOtherHolder) {
  // Pairwise distances: 0-1 is 5, 0-2 is 12, 1-2 is sqrt(9 + 16 + 144) = 13.
  Team team = perfect_trajectories(3, 3);
  team.results[0].objects = {object(4, Eigen::Vector3d(0, 0, 0))};
  team.results[1].objects = {object(4, Eigen::Vector3d(3, 4, 0))};
  team.results[2].objects = {object(4, Eigen::Vector3d(0, 0, 12))};
  const TeamMetrics metrics = evaluate(team.truths, team.results, {});
  EXPECT_DOUBLE_EQ(metrics.robots[0].disagreement, 8.5);
  EXPECT_DOUBLE_EQ(metrics.robots[1].disagreement, 9.0);
  EXPECT_DOUBLE_EQ(metrics.robots[2].disagreement, 12.5);
  for (const RobotMetrics& robot : metrics.robots) EXPECT_EQ(robot.disagreement_pairs, 2);
  EXPECT_DOUBLE_EQ(metrics.average.disagreement, 10.0);
  EXPECT_DOUBLE_EQ(metrics.maximum.disagreement, 12.5);
}

TEST(EvaluationTest, AverageAndMaximumSkipNaN) {
  // Object errors 1, 3 and none (NaN); frames 2, 2 and 3.
  Team team = perfect_trajectories(2, 2);
  team.truths.push_back(wiggly_truth(3));
  team.results.push_back({team.truths.back().groundtruth, {}, {}});
  const std::map<LandmarkId, Eigen::Vector3d> objects_groundtruth = {{1, Eigen::Vector3d::Zero()}};
  team.results[0].objects = {object(1, Eigen::Vector3d(0, 0, 1))};
  team.results[1].objects = {object(1, Eigen::Vector3d(0, 3, 0))};

  const TeamMetrics metrics = evaluate(team.truths, team.results, objects_groundtruth);
  ASSERT_TRUE(std::isnan(metrics.robots[2].object_error));
  EXPECT_DOUBLE_EQ(metrics.average.object_error, 2.0);
  EXPECT_DOUBLE_EQ(metrics.maximum.object_error, 3.0);
  EXPECT_EQ(metrics.average.robot, -1);
  EXPECT_EQ(metrics.maximum.robot, -1);
  EXPECT_EQ(metrics.average.frames, 2);  // 7 / 3 rounded
  EXPECT_EQ(metrics.maximum.frames, 3);
  EXPECT_EQ(metrics.average.objects_evaluated, 1);  // 2 / 3 rounded
  // Robots 0 and 1 disagree by |(0,0,1) - (0,3,0)| = sqrt(10); robot 2 holds nothing.
  EXPECT_DOUBLE_EQ(metrics.average.disagreement, std::sqrt(10.0));
  EXPECT_DOUBLE_EQ(metrics.maximum.disagreement, std::sqrt(10.0));
}

TEST(EvaluationTest, AllNaNFieldStaysNaN) {
  const Team team = perfect_trajectories(2, 2);
  const TeamMetrics metrics = evaluate(team.truths, team.results, {});
  EXPECT_TRUE(std::isnan(metrics.average.object_error));
  EXPECT_TRUE(std::isnan(metrics.maximum.object_error));
}

TEST(EvaluationTest, TrajectoryLengthMismatchThrowsNamingRobotAndLengths) {
  Team team = perfect_trajectories(2, 6);
  team.results[1].trajectory.resize(4);
  try {
    evaluate(team.truths, team.results, {});
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& error) {
    const std::string message = error.what();
    EXPECT_NE(message.find("robot 1"), std::string::npos) << message;
    EXPECT_NE(message.find('4'), std::string::npos) << message;
    EXPECT_NE(message.find('6'), std::string::npos) << message;
  }
}

TEST(EvaluationTest, BadInputsThrow) {
  Team team = perfect_trajectories(2, 6);
  EXPECT_THROW(evaluate(team.truths, {team.results[0]}, {}), std::invalid_argument);
  Team short_odometry = team;
  short_odometry.truths[0].odometry.pop_back();
  EXPECT_THROW(evaluate(short_odometry.truths, short_odometry.results, {}), std::invalid_argument);
  team.results[0].objects = {object(3, Eigen::Vector3d::Zero()),
                             object(3, Eigen::Vector3d::Ones())};
  EXPECT_THROW(evaluate(team.truths, team.results, {}), std::invalid_argument);
}

TEST(EvaluationTest, JsonWritesNullForNaN) {
  Team team = perfect_trajectories(2, 3);
  team.results[0].objects = {object(1, Eigen::Vector3d(0, 0, 0))};
  team.results[1].objects = {object(1, Eigen::Vector3d(0, 0, 2))};
  const nlohmann::json json = to_json(evaluate(team.truths, team.results, {}));
  ASSERT_EQ(json.at("robots").size(), 2u);
  EXPECT_TRUE(json.at("robots").at(0).at("object_error").is_null());
  EXPECT_TRUE(json.at("average").at("object_error").is_null());
  EXPECT_DOUBLE_EQ(json.at("robots").at(1).at("disagreement").get<double>(), 2.0);
  EXPECT_EQ(json.at("robots").at(1).at("robot").get<int>(), 1);
  EXPECT_EQ(json.at("maximum").at("robot").get<int>(), -1);
  EXPECT_EQ(json.at("average").at("frames").get<int>(), 3);
  EXPECT_NE(json.dump().find("null"), std::string::npos);
}

TEST(EvaluationTest, TableHasRobotRowsAverageMaximumAndDashesForNaN) {
  Team team = perfect_trajectories(2, 3);
  team.results[0].objects = {object(1, Eigen::Vector3d(0, 0, 0))};
  team.results[1].objects = {object(1, Eigen::Vector3d(3, 4, 0))};
  const std::string table =
      format_table(evaluate(team.truths, team.results, {}), "Object-only run");
  EXPECT_EQ(table.rfind("Object-only run\n", 0), 0u) << table;
  for (const char* expected : {"traj RMSE m", "odom RMSE m", "object err m", "disagreement m",
                               "objects", "Robot 0", "Robot 1", "Avg", "Max", "5.000", " -"}) {
    EXPECT_NE(table.find(expected), std::string::npos) << expected << " missing in\n" << table;
  }
}

TEST(EvaluationTest, TopViewIsAReadablePngOfTheExpectedSize) {
  Team team = perfect_trajectories(2, 30);
  for (Eigen::Isometry3d& T_world_body : team.truths[1].groundtruth) {
    T_world_body.translation() += Eigen::Vector3d(0, 10, 0);
  }
  team.results[1].trajectory = team.truths[1].groundtruth;
  for (Eigen::Isometry3d& T_world_body : team.results[0].trajectory) {
    T_world_body.translation() += Eigen::Vector3d(0.5, -0.5, 0);
  }
  const std::map<LandmarkId, Eigen::Vector3d> objects_groundtruth = {
      {1, Eigen::Vector3d(10, 5, 0)}, {2, Eigen::Vector3d(40, -3, 0)}};
  team.results[0].objects = {object(1, Eigen::Vector3d(11, 5, 0))};
  team.results[1].objects = {object(1, Eigen::Vector3d(9, 6, 0)),
                             object(2, Eigen::Vector3d(41, -2, 0))};

  const std::filesystem::path file =
      std::filesystem::path(::testing::TempDir()) / "concord_evaluation_top_view.png";
  std::filesystem::remove(file);
  write_top_view_png(file, team.truths, team.results, objects_groundtruth, "two robots");

  ASSERT_TRUE(std::filesystem::exists(file));
  EXPECT_GT(std::filesystem::file_size(file), 0u);
  const cv::Mat image = cv::imread(file.string(), cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(image.empty());
  EXPECT_EQ(image.cols, 1400);
  EXPECT_EQ(image.rows, 1100);
  EXPECT_EQ(image.cols, kTopViewWidth);
  EXPECT_EQ(image.rows, kTopViewHeight);
  double darkest = 0.0;
  double brightest = 0.0;
  cv::minMaxLoc(image, &darkest, &brightest);
  EXPECT_LT(darkest, brightest);

  // The trajectories and objects are drawn in colour in the plot, left of the legend column.
  const cv::Mat colour = cv::imread(file.string(), cv::IMREAD_COLOR);
  ASSERT_EQ(colour.type(), CV_8UC3);
  int coloured_pixels = 0;
  for (int row = 0; row < colour.rows; ++row) {
    for (int column = 0; column < colour.cols / 2; ++column) {
      const cv::Vec3b pixel = colour.at<cv::Vec3b>(row, column);
      if (pixel[0] != pixel[1] || pixel[1] != pixel[2]) ++coloured_pixels;
    }
  }
  EXPECT_GT(coloured_pixels, 500);
  std::filesystem::remove(file);
}

TEST(EvaluationTest, TopViewThatCannotBeWrittenThrowsNamingTheFile) {
  const Team team = perfect_trajectories(1, 3);
  const std::filesystem::path file =
      std::filesystem::path(::testing::TempDir()) / "no_such_directory" / "top_view.png";
  try {
    write_top_view_png(file, team.truths, team.results, {}, "unwritable");
    FAIL() << "expected std::runtime_error";
  } catch (const std::runtime_error& error) {
    EXPECT_NE(std::string(error.what()).find(file.string()), std::string::npos) << error.what();
  }
}

}  // namespace
}  // namespace concord::evaluation
