#include "concord/dataset/dataset.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include "concord/dataset/result_io.h"

namespace concord::dataset {
namespace {

using ::testing::AnyOf;
using ::testing::HasSubstr;

/// The DatasetError message of `action`; fails the test if it throws nothing or something else.
template <typename Action>
std::string dataset_error_message(Action&& action) {
  try {
    action();
  } catch (const DatasetError& error) {
    return error.what();
  }
  ADD_FAILURE() << "expected a DatasetError";
  return {};
}

void write_text(const std::filesystem::path& file, const std::string& text) {
  std::ofstream stream(file, std::ios::binary);
  stream << text;
  ASSERT_TRUE(stream.good()) << file;
}

std::string read_text(const std::filesystem::path& file) {
  std::ifstream stream(file, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(stream)), std::istreambuf_iterator<char>());
}

Eigen::Isometry3d make_pose(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation) {
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = rotation;
  pose.translation() = translation;
  return pose;
}

/// A folder of its own under the test temporary directory, removed afterwards.
class DatasetFilesTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const ::testing::TestInfo* info = ::testing::UnitTest::GetInstance()->current_test_info();
    folder_ = std::filesystem::path(::testing::TempDir()) /
              ("concord_" + std::string(info->test_suite_name()) + "_" + info->name() + "_" +
               std::to_string(::getpid()));
    std::filesystem::remove_all(folder_);
    std::filesystem::create_directories(folder_);
  }
  void TearDown() override { std::filesystem::remove_all(folder_); }

  std::filesystem::path folder_;
};

constexpr char kDescription[] = R"({
  "name": "tiny",
  "robots": 2,
  "camera": {
    "K": [[500.0, 0.0, 320.0], [0.0, 510.0, 240.0], [0.0, 0.0, 1.0]],
    "T_cam_body": [[0, -1, 0, 0.1], [0, 0, -1, 0.2], [1, 0, 0, 0.3], [0, 0, 0, 1]],
    "T_cam0_cam1": [[1, 0, 0, 0.5], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
    "fx_times_baseline": 250.0
  }
})";

constexpr char kObjectsGroundtruth[] = "id,x,y,z\n7,1.5,-2.25,3\n3,10,20,30.125\n";

/// Robot 0: 3 frames, objects and features. Robot 1: 2 frames, one object, no features.
constexpr char kGroundtruth0[] =
    "1 0 0 0 0 1 0 0 0 0 1 0\n"
    "0 -1 0 1 1 0 0 2 0 0 1 3\n"
    "1 0 0 4.5 0 1 0 0 0 0 1 -0.5\n";
constexpr char kOdometry0[] =
    "0 -1 0 1 1 0 0 2 0 0 1 3\n"
    "0 1 0 -2 -1 0 0 3.5 0 0 1 -3.5\n";
constexpr char kObjects0[] =
    "frame,id,u_left,v_left,u_right,v_right\n"
    "0,7,100.5,200,90.5,200\n"
    "0,3,300,100,280,100\n"
    "2,7,110,210,95,210.25\n";
constexpr char kFeatures0[] =
    "frame,id,u_left,v_left,u_right,v_right\n"
    "1,1000,10,20,5,20\n";
constexpr char kGroundtruth1[] =
    "1 0 0 5 0 1 0 5 0 0 1 0\n"
    "1 0 0 6 0 1 0 5 0 0 1 0\n";
constexpr char kOdometry1[] = "1 0 0 1 0 1 0 0 0 0 1 0\n";
constexpr char kObjects1[] =
    "frame,id,u_left,v_left,u_right,v_right\n"
    "1,3,1,2,0.5,2\n";

class DatasetTest : public DatasetFilesTest {
 protected:
  void SetUp() override {
    DatasetFilesTest::SetUp();
    dataset_folder_ = folder_ / "tiny";
    write_fixture();
  }

  /// (Re)writes the valid fixture, undoing earlier changes.
  void write_fixture() {
    std::filesystem::remove_all(dataset_folder_);
    std::filesystem::create_directories(robot_folder(0));
    std::filesystem::create_directories(robot_folder(1));
    write_text(dataset_folder_ / "dataset.json", kDescription);
    write_text(dataset_folder_ / "objects_gt.csv", kObjectsGroundtruth);
    write_text(robot_folder(0) / "groundtruth.kitti", kGroundtruth0);
    write_text(robot_folder(0) / "odometry.kitti", kOdometry0);
    write_text(robot_folder(0) / "objects.csv", kObjects0);
    write_text(robot_folder(0) / "features.csv", kFeatures0);
    write_text(robot_folder(1) / "groundtruth.kitti", kGroundtruth1);
    write_text(robot_folder(1) / "odometry.kitti", kOdometry1);
    write_text(robot_folder(1) / "objects.csv", kObjects1);
  }

  std::filesystem::path robot_folder(int index) const {
    return dataset_folder_ / ("robot_0" + std::to_string(index));
  }

  /// The DatasetError message of reading the fixture after replacing `relative_file` by `text`.
  std::string error_reading_with(const std::string& relative_file, const std::string& text) {
    write_fixture();
    write_text(dataset_folder_ / relative_file, text);
    return dataset_error_message([&] { read_dataset(dataset_folder_); });
  }

  std::filesystem::path dataset_folder_;
};

TEST_F(DatasetTest, ReadsTheFixture) {
  const Dataset dataset = read_dataset(dataset_folder_);
  EXPECT_EQ(dataset.name, "tiny");
  EXPECT_EQ(dataset.root, dataset_folder_);

  Eigen::Matrix3d expected_intrinsics;
  expected_intrinsics << 500, 0, 320, 0, 510, 240, 0, 0, 1;
  EXPECT_EQ(dataset.camera.K, expected_intrinsics);
  Eigen::Matrix4d expected_cam0_body;
  expected_cam0_body << 0, -1, 0, 0.1, 0, 0, -1, 0.2, 1, 0, 0, 0.3, 0, 0, 0, 1;
  EXPECT_EQ(dataset.camera.T_cam0_body.matrix(), expected_cam0_body);
  EXPECT_EQ(dataset.camera.T_cam0_cam1.translation(), Eigen::Vector3d(0.5, 0, 0));
  EXPECT_EQ(dataset.camera.T_cam0_cam1.linear(), Eigen::Matrix3d::Identity());

  ASSERT_EQ(dataset.objects_groundtruth.size(), 2u);
  EXPECT_EQ(dataset.objects_groundtruth.at(7), Eigen::Vector3d(1.5, -2.25, 3));
  EXPECT_EQ(dataset.objects_groundtruth.at(3), Eigen::Vector3d(10, 20, 30.125));

  ASSERT_EQ(dataset.robots.size(), 2u);
  const RobotData& robot0 = dataset.robots[0];
  EXPECT_EQ(robot0.index, 0);
  ASSERT_EQ(robot0.num_frames(), 3);
  ASSERT_EQ(robot0.odometry.size(), 2u);
  Eigen::Matrix4d expected_second_pose;
  expected_second_pose << 0, -1, 0, 1, 1, 0, 0, 2, 0, 0, 1, 3, 0, 0, 0, 1;
  EXPECT_EQ(robot0.groundtruth[1].matrix(), expected_second_pose);
  EXPECT_EQ(robot0.groundtruth[2].translation(), Eigen::Vector3d(4.5, 0, -0.5));
  EXPECT_EQ(robot0.odometry[1].translation(), Eigen::Vector3d(-2, 3.5, -3.5));
  ASSERT_EQ(robot0.objects.size(), 3u);
  ASSERT_EQ(robot0.objects[0].size(), 2u);
  EXPECT_EQ(robot0.objects[0][0].id, 7);
  EXPECT_EQ(robot0.objects[0][0].uv, Eigen::Vector4d(100.5, 200, 90.5, 200));
  EXPECT_EQ(robot0.objects[0][1].id, 3);
  EXPECT_TRUE(robot0.objects[1].empty());
  ASSERT_EQ(robot0.objects[2].size(), 1u);
  EXPECT_EQ(robot0.objects[2][0].uv, Eigen::Vector4d(110, 210, 95, 210.25));
  EXPECT_TRUE(robot0.has_features);
  ASSERT_EQ(robot0.features.size(), 3u);
  ASSERT_EQ(robot0.features[1].size(), 1u);
  EXPECT_EQ(robot0.features[1][0].id, 1000);
  EXPECT_EQ(robot0.features[1][0].uv, Eigen::Vector4d(10, 20, 5, 20));

  const RobotData& robot1 = dataset.robots[1];
  EXPECT_EQ(robot1.index, 1);
  EXPECT_EQ(robot1.num_frames(), 2);
  EXPECT_FALSE(robot1.has_features);
  ASSERT_EQ(robot1.features.size(), 2u);
  EXPECT_TRUE(robot1.features[0].empty() && robot1.features[1].empty());
  ASSERT_EQ(robot1.objects[1].size(), 1u);
  EXPECT_EQ(robot1.objects[1][0].id, 3);
}

TEST_F(DatasetTest, FrameInputCarriesOdometryObjectsAndFeatures) {
  const Dataset dataset = read_dataset(dataset_folder_);
  const RobotData& robot = dataset.robots[0];

  const FrameInput first = robot.frame_input(0);
  EXPECT_EQ(first.frame, 0);
  EXPECT_FALSE(first.T_previous_current.has_value());
  EXPECT_EQ(first.objects.size(), 2u);
  EXPECT_TRUE(first.features.empty());

  const FrameInput second = robot.frame_input(1);
  EXPECT_EQ(second.frame, 1);
  ASSERT_TRUE(second.T_previous_current.has_value());
  EXPECT_EQ(second.T_previous_current->matrix(), robot.odometry[0].matrix());
  EXPECT_TRUE(second.objects.empty());
  ASSERT_EQ(second.features.size(), 1u);
  EXPECT_EQ(second.features[0].id, 1000);

  const FrameInput third = robot.frame_input(2);
  EXPECT_EQ(third.T_previous_current->matrix(), robot.odometry[1].matrix());

  EXPECT_THROW(robot.frame_input(3), std::out_of_range);
  EXPECT_THROW(robot.frame_input(-1), std::out_of_range);
}

TEST_F(DatasetTest, NameDefaultsToTheFolderName) {
  write_text(dataset_folder_ / "dataset.json",
             R"({"camera": {"K": [[1,0,0],[0,1,0],[0,0,1]],
                 "T_cam_body": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]],
                 "T_cam0_cam1": [[1,0,0,0.5],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}})");
  EXPECT_EQ(read_dataset(dataset_folder_).name, "tiny");
  EXPECT_EQ(read_dataset(dataset_folder_.string() + "/").name, "tiny");
}

TEST_F(DatasetTest, ObjectsGroundtruthIsOptional) {
  std::filesystem::remove(dataset_folder_ / "objects_gt.csv");
  EXPECT_TRUE(read_dataset(dataset_folder_).objects_groundtruth.empty());
}

TEST_F(DatasetTest, AcceptsWindowsLineEndsAndTrailingBlankLines) {
  write_text(robot_folder(0) / "groundtruth.kitti",
             "1 0 0 0 0 1 0 0 0 0 1 0\r\n"
             "0 -1 0 1 1 0 0 2 0 0 1 3\r\n"
             "1 0 0 4.5 0 1 0 0 0 0 1 -0.5\r\n\r\n\n");
  write_text(robot_folder(0) / "objects.csv",
             "frame,id,u_left,v_left,u_right,v_right\r\n0,7,1,2,3,4\r\n\n");
  const Dataset dataset = read_dataset(dataset_folder_);
  EXPECT_EQ(dataset.robots[0].num_frames(), 3);
  EXPECT_EQ(dataset.robots[0].objects[0].at(0).uv, Eigen::Vector4d(1, 2, 3, 4));
}

TEST_F(DatasetTest, MaxFramesDropsLaterFramesAndObservations) {
  ReadOptions options;
  options.max_frames = 2;
  const Dataset dataset = read_dataset(dataset_folder_, options);
  const RobotData& robot = dataset.robots[0];
  EXPECT_EQ(robot.num_frames(), 2);
  EXPECT_EQ(robot.odometry.size(), 1u);
  EXPECT_EQ(robot.objects.size(), 2u);
  EXPECT_EQ(robot.features.size(), 2u);
  EXPECT_EQ(robot.objects[0].size(), 2u);
  EXPECT_EQ(robot.features[1].size(), 1u);
  // Robot 1 has only 2 frames: unchanged.
  EXPECT_EQ(dataset.robots[1].num_frames(), 2);
  EXPECT_EQ(dataset.robots[1].odometry.size(), 1u);

  options.max_frames = 1;
  const Dataset one_frame = read_dataset(dataset_folder_, options);
  EXPECT_EQ(one_frame.robots[0].num_frames(), 1);
  EXPECT_TRUE(one_frame.robots[0].odometry.empty());

  options.max_frames = 0;
  EXPECT_THROW(read_dataset(dataset_folder_, options), std::invalid_argument);
}

TEST_F(DatasetTest, MaxRobotsAndLoadFeatures) {
  ReadOptions options;
  options.max_robots = 1;
  options.load_features = false;
  const Dataset dataset = read_dataset(dataset_folder_, options);
  ASSERT_EQ(dataset.robots.size(), 1u);
  EXPECT_FALSE(dataset.robots[0].has_features);
  ASSERT_EQ(dataset.robots[0].features.size(), 3u);
  EXPECT_TRUE(dataset.robots[0].features[1].empty());

  options.max_robots = 5;
  EXPECT_EQ(read_dataset(dataset_folder_, options).robots.size(), 2u);
  options.max_robots = 0;
  EXPECT_THROW(read_dataset(dataset_folder_, options), std::invalid_argument);
}

TEST_F(DatasetTest, OnlyRobotReadsOneFolder) {
  const Dataset whole = read_dataset(dataset_folder_);
  ReadOptions options;
  options.only_robot = 1;
  const Dataset one = read_dataset(dataset_folder_, options);
  ASSERT_EQ(one.robots.size(), 1u);
  EXPECT_EQ(one.robots[0].index, 1);
  EXPECT_EQ(one.robots[0].num_frames(), whole.robots[1].num_frames());
  EXPECT_TRUE(one.robots[0].groundtruth.back().isApprox(whole.robots[1].groundtruth.back(), 0.0));
  options.only_robot = 2;
  EXPECT_THROW(read_dataset(dataset_folder_, options), DatasetError);
  options.only_robot = -1;
  EXPECT_THROW(read_dataset(dataset_folder_, options), std::invalid_argument);
}

// --- Missing files and folders ---

TEST_F(DatasetTest, MissingDatasetFolder) {
  const std::string message =
      dataset_error_message([&] { read_dataset(folder_ / "does_not_exist"); });
  EXPECT_THAT(message, HasSubstr("does_not_exist"));
  EXPECT_THAT(message, HasSubstr("not found"));
}

TEST_F(DatasetTest, MissingFilesAreNamed) {
  for (const std::string relative_file : {"dataset.json", "robot_00/groundtruth.kitti",
                                          "robot_01/odometry.kitti", "robot_00/objects.csv"}) {
    write_fixture();
    std::filesystem::remove(dataset_folder_ / relative_file);
    const std::string message = dataset_error_message([&] { read_dataset(dataset_folder_); });
    EXPECT_THAT(message, HasSubstr(relative_file + ": file not found"));
  }
}

TEST_F(DatasetTest, RobotFoldersMustBeConsecutive) {
  std::filesystem::rename(robot_folder(1), dataset_folder_ / "robot_02");
  const std::string message = dataset_error_message([&] { read_dataset(dataset_folder_); });
  EXPECT_THAT(message, HasSubstr("robot_01"));
  EXPECT_THAT(message, HasSubstr("consecutively"));
}

TEST_F(DatasetTest, MalformedRobotFolderName) {
  std::filesystem::create_directories(dataset_folder_ / "robot_x");
  EXPECT_THAT(dataset_error_message([&] { read_dataset(dataset_folder_); }),
              HasSubstr("robot_x: robot folders must be named robot_NN"));
}

TEST_F(DatasetTest, NoRobotFolders) {
  std::filesystem::remove_all(robot_folder(0));
  std::filesystem::remove_all(robot_folder(1));
  EXPECT_THAT(dataset_error_message([&] { read_dataset(dataset_folder_); }),
              HasSubstr("no robot_NN folders"));
}

// --- dataset.json ---

TEST_F(DatasetTest, DescriptionRobotCountMustMatchTheFolders) {
  std::string text = kDescription;
  text.replace(text.find("\"robots\": 2"), 11, "\"robots\": 3");
  const std::string message = error_reading_with("dataset.json", text);
  EXPECT_THAT(message, HasSubstr("dataset.json"));
  EXPECT_THAT(message, HasSubstr("\"robots\" is 3 but the folder has 2"));
}

TEST_F(DatasetTest, DescriptionMustBeValidJson) {
  const std::string message = error_reading_with("dataset.json", "{\"name\": \"tiny\",\n}");
  EXPECT_THAT(message, HasSubstr("dataset.json: invalid JSON"));
  EXPECT_THAT(message, HasSubstr("line 2"));
}

TEST_F(DatasetTest, DescriptionCameraIsChecked) {
  std::string missing_intrinsics = kDescription;
  missing_intrinsics.replace(missing_intrinsics.find("\"K\""), 3, "\"k\"");
  EXPECT_THAT(error_reading_with("dataset.json", missing_intrinsics),
              HasSubstr("dataset.json: missing camera.K"));

  std::string short_row = kDescription;
  short_row.replace(short_row.find("[1, 0, 0, 0.3]"), 14, "[1, 0, 0]");
  EXPECT_THAT(error_reading_with("dataset.json", short_row),
              HasSubstr("camera.T_cam_body must be a 4x4 array of numbers"));

  std::string not_rotation = kDescription;
  not_rotation.replace(not_rotation.find("[[1, 0, 0, 0.5]"), 15, "[[2, 0, 0, 0.5]");
  EXPECT_THAT(error_reading_with("dataset.json", not_rotation),
              HasSubstr("camera.T_cam0_cam1: rotation block is not a rotation"));
}

// --- KITTI files ---

TEST_F(DatasetTest, KittiLineWithoutTwelveNumbers) {
  const std::string message = error_reading_with(
      "robot_00/groundtruth.kitti",
      "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1\n1 0 0 0 0 1 0 0 0 0 1 0\n");
  EXPECT_THAT(message, HasSubstr("robot_00/groundtruth.kitti:2:"));
  EXPECT_THAT(message, HasSubstr("expected 12 numbers"));
  EXPECT_THAT(message, HasSubstr("found 11"));

  EXPECT_THAT(error_reading_with("robot_00/odometry.kitti",
                                 "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 0 7\n"),
              HasSubstr("robot_00/odometry.kitti:2: expected 12 numbers (a 3x4 pose, row-major), "
                        "found 13"));
}

TEST_F(DatasetTest, KittiBlankLineInTheMiddle) {
  EXPECT_THAT(error_reading_with("robot_01/groundtruth.kitti",
                                 "1 0 0 5 0 1 0 5 0 0 1 0\n\n1 0 0 6 0 1 0 5 0 0 1 0\n"),
              HasSubstr("robot_01/groundtruth.kitti:2: expected 12 numbers"));
}

TEST_F(DatasetTest, KittiNonNumericToken) {
  const std::string message = error_reading_with(
      "robot_00/odometry.kitti", "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 x2 0 0 1 0\n");
  EXPECT_THAT(message, HasSubstr("robot_00/odometry.kitti:2:"));
  EXPECT_THAT(message, HasSubstr("entry 8 'x2' is not a number"));
  EXPECT_THAT(error_reading_with("robot_00/odometry.kitti",
                                 "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 2.5.1 0 0 1 0\n"),
              HasSubstr("odometry.kitti:2: entry 8 '2.5.1' is not a number"));
}

TEST_F(DatasetTest, KittiNotFiniteNumbers) {
  EXPECT_THAT(error_reading_with("robot_00/groundtruth.kitti",
                                 "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 0\n"
                                 "1 0 0 nan 0 1 0 0 0 0 1 0\n"),
              HasSubstr("groundtruth.kitti:3: entry 4 'nan' is not finite"));
  EXPECT_THAT(error_reading_with("robot_00/groundtruth.kitti",
                                 "1 0 0 -inf 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 0\n"
                                 "1 0 0 0 0 1 0 0 0 0 1 0\n"),
              HasSubstr("groundtruth.kitti:1: entry 4 '-inf' is not finite"));
  EXPECT_THAT(error_reading_with("robot_00/groundtruth.kitti",
                                 "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 1e999 0 1 0 0 0 0 1 0\n"
                                 "1 0 0 0 0 1 0 0 0 0 1 0\n"),
              HasSubstr("groundtruth.kitti:2: entry 4 '1e999' is out of the range"));
}

TEST_F(DatasetTest, KittiRotationBlockMustBeARotation) {
  const std::string scaled = error_reading_with(
      "robot_00/groundtruth.kitti",
      "1 0 0 0 0 1 0 0 0 0 1 0\n1.1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 0\n");
  EXPECT_THAT(scaled, HasSubstr("groundtruth.kitti:2: rotation block is not a rotation"));

  const std::string reflection = error_reading_with(
      "robot_00/groundtruth.kitti",
      "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 -1 0\n");
  EXPECT_THAT(reflection, HasSubstr("groundtruth.kitti:3: rotation block is a reflection"));
}

TEST_F(DatasetTest, KittiSmallRotationErrorsAreOrthonormalized) {
  write_text(robot_folder(0) / "groundtruth.kitti",
             "1.0002 0.0001 0 0 0 0.9999 0 0 0 0 1 0\n"
             "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 0\n");
  const Dataset dataset = read_dataset(dataset_folder_);
  const Eigen::Matrix3d rotation = dataset.robots[0].groundtruth[0].linear();
  EXPECT_LT((rotation.transpose() * rotation - Eigen::Matrix3d::Identity()).norm(), 1e-12);
  EXPECT_NEAR(rotation.determinant(), 1.0, 1e-12);
  EXPECT_NEAR(rotation(0, 0), 1.0, 1e-3);
}

TEST_F(DatasetTest, OdometryMustHaveOneLineFewerThanGroundtruth) {
  const std::string message =
      error_reading_with("robot_00/odometry.kitti", "1 0 0 0 0 1 0 0 0 0 1 0\n");
  EXPECT_THAT(message, HasSubstr("robot_00/odometry.kitti: 1 poses, expected 2"));
  EXPECT_THAT(message, HasSubstr("groundtruth.kitti"));
}

TEST_F(DatasetTest, EmptyGroundtruth) {
  EXPECT_THAT(error_reading_with("robot_01/groundtruth.kitti", ""),
              HasSubstr("robot_01/groundtruth.kitti: no poses"));
}

// --- CSV files ---

TEST_F(DatasetTest, CsvHeaderMissing) {
  EXPECT_THAT(
      error_reading_with("robot_00/objects.csv", "0,7,100.5,200,90.5,200\n"),
      HasSubstr("robot_00/objects.csv:1: expected the header "
                "'frame,id,u_left,v_left,u_right,v_right', found '0,7,100.5,200,90.5,200'"));
  EXPECT_THAT(error_reading_with("robot_00/objects.csv", ""),
              HasSubstr("robot_00/objects.csv: empty file, expected the header"));
  EXPECT_THAT(error_reading_with("objects_gt.csv", "7,1.5,-2.25,3\n"),
              HasSubstr("objects_gt.csv:1: expected the header 'id,x,y,z'"));
}

TEST_F(DatasetTest, CsvHeaderWrong) {
  EXPECT_THAT(error_reading_with("robot_00/features.csv", "frame,id,u,v,u_right,v_right\n"),
              HasSubstr("robot_00/features.csv:1: expected the header"));
  EXPECT_THAT(error_reading_with("robot_00/features.csv", "frame,id,u_left,v_left,u_right\n"),
              HasSubstr("robot_00/features.csv:1: expected the header"));
}

TEST_F(DatasetTest, CsvRowWithWrongColumnCount) {
  EXPECT_THAT(
      error_reading_with("robot_00/objects.csv",
                         "frame,id,u_left,v_left,u_right,v_right\n0,7,1,2,3,4\n0,3,1,2,3\n"),
      HasSubstr("robot_00/objects.csv:3: expected 6 comma-separated fields, found 5"));
  EXPECT_THAT(error_reading_with("objects_gt.csv", "id,x,y,z\n1,2,3,4\n2,3,4,5\n3,4,5,6,7\n"),
              HasSubstr("objects_gt.csv:4: expected 4 comma-separated fields, found 5"));
}

TEST_F(DatasetTest, CsvNonNumericValue) {
  EXPECT_THAT(error_reading_with("robot_00/objects.csv",
                                 "frame,id,u_left,v_left,u_right,v_right\n0,7,1,abc,3,4\n"),
              HasSubstr("robot_00/objects.csv:2: v_left 'abc' is not a number"));
  EXPECT_THAT(error_reading_with("objects_gt.csv", "id,x,y,z\n1,2,3,inf\n"),
              HasSubstr("objects_gt.csv:2: z 'inf' is not finite"));
}

TEST_F(DatasetTest, CsvFrameOutOfRange) {
  EXPECT_THAT(
      error_reading_with("robot_00/objects.csv",
                         "frame,id,u_left,v_left,u_right,v_right\n0,7,1,2,3,4\n-1,7,1,2,3,4\n"),
      HasSubstr("robot_00/objects.csv:3: frame -1 is outside [0, 2]"));
  EXPECT_THAT(error_reading_with("robot_01/objects.csv",
                                 "frame,id,u_left,v_left,u_right,v_right\n2,7,1,2,3,4\n"),
              HasSubstr("robot_01/objects.csv:2: frame 2 is outside [0, 1]"));
  EXPECT_THAT(error_reading_with("robot_00/features.csv",
                                 "frame,id,u_left,v_left,u_right,v_right\n1.5,7,1,2,3,4\n"),
              HasSubstr("robot_00/features.csv:2: frame '1.5' is not an integer"));
}

TEST_F(DatasetTest, CsvNonIntegerId) {
  EXPECT_THAT(error_reading_with("robot_00/objects.csv",
                                 "frame,id,u_left,v_left,u_right,v_right\n0,7.5,1,2,3,4\n"),
              HasSubstr("robot_00/objects.csv:2: id '7.5' is not an integer"));
  EXPECT_THAT(error_reading_with("objects_gt.csv", "id,x,y,z\n1,2,3,4\ncar,2,3,4\n"),
              HasSubstr("objects_gt.csv:3: id 'car' is not an integer"));
  EXPECT_THAT(error_reading_with("robot_00/features.csv",
                                 "frame,id,u_left,v_left,u_right,v_right\n0,,1,2,3,4\n"),
              HasSubstr("robot_00/features.csv:2: id '' is not an integer"));
}

TEST_F(DatasetTest, DuplicateIdInObjectsGroundtruth) {
  EXPECT_THAT(error_reading_with("objects_gt.csv", "id,x,y,z\n7,1,2,3\n3,1,2,3\n7,4,5,6\n"),
              HasSubstr("objects_gt.csv:4: duplicate id 7"));
}

// --- Writing and slicing ---

/// A dataset with awkward numbers (random rotations, values without short decimal forms).
Dataset random_dataset() {
  std::mt19937 generator(42);
  std::uniform_real_distribution<double> uniform(-100.0, 100.0);
  const auto random_rotation = [&] {
    Eigen::Quaterniond rotation{uniform(generator), uniform(generator), uniform(generator),
                                uniform(generator)};  // braces: evaluated in order
    return rotation.normalized().toRotationMatrix();
  };
  const auto random_pose = [&] {
    return make_pose(random_rotation(),
                     {uniform(generator), uniform(generator), uniform(generator) / 3.0});
  };

  Dataset dataset;
  dataset.name = "random";
  dataset.camera.K << 718.856, 0, 607.1928, 0, 718.856 + 1.0 / 3.0, 185.2157, 0, 0, 1;
  dataset.camera.T_cam0_body = random_pose();
  dataset.camera.T_cam0_cam1 = make_pose(Eigen::Matrix3d::Identity(), {0.53233185784079, 0, 0});
  for (LandmarkId id = 0; id < 20; id += 3) {
    dataset.objects_groundtruth[id] = {uniform(generator), uniform(generator) / 7.0, 1e-9};
  }
  for (int robot_index = 0; robot_index < 3; ++robot_index) {
    RobotData robot;
    robot.index = robot_index;
    const int frames = 5 + robot_index;
    robot.objects.resize(frames);
    robot.features.resize(frames);
    robot.has_features = robot_index == 1;
    for (int frame = 0; frame < frames; ++frame) {
      robot.groundtruth.push_back(random_pose());
      if (frame > 0) robot.odometry.push_back(random_pose());
      for (LandmarkId id = frame; id < frame + 3; ++id) {
        StereoObservation observation;
        observation.id = id;
        observation.uv = {uniform(generator), uniform(generator), uniform(generator) * 1e-7,
                          uniform(generator) * 1e7};
        robot.objects[frame].push_back(observation);
        if (robot.has_features) {
          observation.id = 1000000000000 + id;
          robot.features[frame].push_back(observation);
        }
      }
    }
    dataset.robots.push_back(robot);
  }
  return dataset;
}

void expect_same_poses(const std::vector<Eigen::Isometry3d>& actual,
                       const std::vector<Eigen::Isometry3d>& expected) {
  ASSERT_EQ(actual.size(), expected.size());
  for (std::size_t index = 0; index < actual.size(); ++index) {
    EXPECT_EQ(actual[index].matrix(), expected[index].matrix()) << "pose " << index;
  }
}

void expect_same_observations(const std::vector<std::vector<StereoObservation>>& actual,
                              const std::vector<std::vector<StereoObservation>>& expected) {
  ASSERT_EQ(actual.size(), expected.size());
  for (std::size_t frame = 0; frame < actual.size(); ++frame) {
    ASSERT_EQ(actual[frame].size(), expected[frame].size()) << "frame " << frame;
    for (std::size_t index = 0; index < actual[frame].size(); ++index) {
      EXPECT_EQ(actual[frame][index].id, expected[frame][index].id);
      EXPECT_EQ(actual[frame][index].uv, expected[frame][index].uv);
    }
  }
}

/// Bit-for-bit equality of everything a dataset holds except its root.
void expect_same_dataset(const Dataset& actual, const Dataset& expected) {
  EXPECT_EQ(actual.name, expected.name);
  EXPECT_EQ(actual.camera.K, expected.camera.K);
  EXPECT_EQ(actual.camera.T_cam0_body.matrix(), expected.camera.T_cam0_body.matrix());
  EXPECT_EQ(actual.camera.T_cam0_cam1.matrix(), expected.camera.T_cam0_cam1.matrix());
  EXPECT_EQ(actual.objects_groundtruth, expected.objects_groundtruth);
  ASSERT_EQ(actual.robots.size(), expected.robots.size());
  for (std::size_t robot = 0; robot < actual.robots.size(); ++robot) {
    SCOPED_TRACE("robot " + std::to_string(robot));
    EXPECT_EQ(actual.robots[robot].index, expected.robots[robot].index);
    EXPECT_EQ(actual.robots[robot].has_features, expected.robots[robot].has_features);
    expect_same_poses(actual.robots[robot].groundtruth, expected.robots[robot].groundtruth);
    expect_same_poses(actual.robots[robot].odometry, expected.robots[robot].odometry);
    expect_same_observations(actual.robots[robot].objects, expected.robots[robot].objects);
    expect_same_observations(actual.robots[robot].features, expected.robots[robot].features);
  }
}

TEST_F(DatasetFilesTest, WriteThenReadIsExact) {
  const Dataset original = random_dataset();
  write_dataset(original, folder_ / "random");
  const Dataset read_back = read_dataset(folder_ / "random");
  expect_same_dataset(read_back, original);
  EXPECT_TRUE(std::filesystem::exists(folder_ / "random" / "robot_01" / "features.csv"));
  EXPECT_FALSE(std::filesystem::exists(folder_ / "random" / "robot_00" / "features.csv"));

  // Writing what was read gives the same files byte for byte.
  write_dataset(read_back, folder_ / "again");
  for (const std::string relative_file :
       {"dataset.json", "objects_gt.csv", "robot_02/groundtruth.kitti", "robot_02/odometry.kitti",
        "robot_01/objects.csv", "robot_01/features.csv"}) {
    EXPECT_EQ(read_text(folder_ / "again" / relative_file),
              read_text(folder_ / "random" / relative_file))
        << relative_file;
  }
}

/// An odometry_covariance.csv with one row for `frame`: a diagonal covariance with `diagonal`.
std::string odometry_covariance_file(const std::string& frame, double diagonal) {
  std::string text = "frame";
  for (int row = 0; row < 6; ++row)
    for (int column = row; column < 6; ++column)
      text += ",c" + std::to_string(row) + std::to_string(column);
  text += "\n" + frame;
  for (int row = 0; row < 6; ++row)
    for (int column = row; column < 6; ++column)
      text += row == column ? "," + std::to_string(diagonal) : ",0";
  return text + "\n";
}

TEST_F(DatasetTest, OdometryCovarianceIsReadIntoTheFrameInputsAndChecked) {
  write_text(robot_folder(1) / "odometry_covariance.csv", odometry_covariance_file("1", 0.25));
  const Dataset dataset = read_dataset(dataset_folder_);
  const RobotData& robot = dataset.robots[1];
  ASSERT_EQ(robot.odometry_covariance.size(), 1u);
  ASSERT_TRUE(robot.frame_input(1).odometry_covariance);
  EXPECT_EQ(*robot.frame_input(1).odometry_covariance,
            (0.25 * Eigen::Matrix<double, 6, 6>::Identity()).eval());
  EXPECT_FALSE(dataset.robots[0].frame_input(1).odometry_covariance);  // no file: configured
  // Written back with the dataset.
  write_dataset(dataset, folder_ / "copy");
  EXPECT_EQ(read_dataset(folder_ / "copy").robots[1].odometry_covariance, robot.odometry_covariance);

  const std::string file = "robot_01/odometry_covariance.csv";
  EXPECT_THAT(error_reading_with(file, odometry_covariance_file("0", 0.25)),
              HasSubstr("frame 0 outside [1, 2)"));
  EXPECT_THAT(error_reading_with(file, odometry_covariance_file("2", 0.25)),
              HasSubstr("frame 2 outside [1, 2)"));
  EXPECT_THAT(error_reading_with(file, odometry_covariance_file("1", -1.0)),
              HasSubstr("not finite and positive definite"));
  const std::string once = odometry_covariance_file("1", 0.25);
  EXPECT_THAT(error_reading_with(file, once + once.substr(once.find('\n') + 1)),
              HasSubstr("frame 1 given twice"));
}

TEST_F(DatasetTest, FeaturesMayCarryEachObservationsOwnNoise) {
  const std::string header = "frame,id,u_left,v_left,u_right,v_right,sigma_left,sigma_right\n";
  write_text(robot_folder(0) / "features.csv",
             header + "1,1000,10,20,5,20,0.25,0.5\n2,1000,11,20,6,20,0,0\n");
  const Dataset dataset = read_dataset(dataset_folder_);
  const auto& features = dataset.robots[0].features;
  EXPECT_EQ(features[1][0].sigma, Eigen::Vector2d(0.25, 0.5));
  EXPECT_EQ(features[2][0].sigma, Eigen::Vector2d::Zero());  // the configured noise
  // Written back with the columns, and read back the same.
  write_dataset(dataset, folder_ / "copy");
  EXPECT_EQ(read_text(folder_ / "copy" / "robot_00" / "features.csv").substr(0, header.size()),
            header);
  EXPECT_EQ(read_dataset(folder_ / "copy").robots[0].features[1][0].sigma,
            Eigen::Vector2d(0.25, 0.5));

  const std::string file = "robot_00/features.csv";
  for (const std::string row : {"1,1000,10,20,5,20,0.25,0\n", "1,1000,10,20,5,20,-0.25,0.5\n",
                                "1,1000,10,20,5,20,nan,0.5\n", "1,1000,10,20,5,20,1e-300,0.5\n",
                                "1,1000,10,20,5,20,0.25,1e300\n"}) {
    EXPECT_THAT(error_reading_with(file, header + row),
                AnyOf(HasSubstr("sigma_left and sigma_right must both be > 0"),
                      HasSubstr("is not a number"), HasSubstr("is not finite")))
        << row;
  }
  EXPECT_THAT(error_reading_with(file, header + "1,1000,10,20,5,20,0.25\n"),
              HasSubstr("expected 8 comma-separated fields, found 7"));
}

TEST_F(DatasetTest, WriteThenReadTheFixtureIsExact) {
  const Dataset original = read_dataset(dataset_folder_);
  write_dataset(original, folder_ / "copy");
  expect_same_dataset(read_dataset(folder_ / "copy"), original);
  EXPECT_EQ(read_text(folder_ / "copy" / "robot_00" / "objects.csv"), kObjects0);
  EXPECT_EQ(read_text(folder_ / "copy" / "robot_00" / "features.csv"), kFeatures0);
}

TEST_F(DatasetFilesTest, WriteRefusesToLeaveExtraRobotFolders) {
  const Dataset original = random_dataset();
  write_dataset(original, folder_ / "random");
  const Dataset fewer = slice(original, 100, 2);
  EXPECT_THAT(dataset_error_message([&] { write_dataset(fewer, folder_ / "random"); }),
              HasSubstr("robot_02"));

  Dataset inconsistent = original;
  inconsistent.robots[1].odometry.pop_back();
  EXPECT_THROW(write_dataset(inconsistent, folder_ / "other"), std::invalid_argument);
}

TEST_F(DatasetFilesTest, SliceKeepsTheFirstFramesAndRobots) {
  const Dataset original = random_dataset();
  const Dataset cut = slice(original, 3, 2);
  EXPECT_EQ(cut.name, original.name);
  EXPECT_EQ(cut.objects_groundtruth, original.objects_groundtruth);
  ASSERT_EQ(cut.robots.size(), 2u);
  for (std::size_t robot = 0; robot < cut.robots.size(); ++robot) {
    const RobotData& kept = cut.robots[robot];
    const RobotData& source = original.robots[robot];
    EXPECT_EQ(kept.index, source.index);
    ASSERT_EQ(kept.num_frames(), 3);
    ASSERT_EQ(kept.odometry.size(), 2u);
    EXPECT_EQ(kept.objects.size(), 3u);
    EXPECT_EQ(kept.features.size(), 3u);
    for (int frame = 0; frame < 3; ++frame) {
      EXPECT_EQ(kept.groundtruth[frame].matrix(), source.groundtruth[frame].matrix());
      EXPECT_EQ(kept.objects[frame].size(), source.objects[frame].size());
    }
    EXPECT_EQ(kept.odometry[1].matrix(), source.odometry[1].matrix());
  }

  // A slice written and read back with max_frames on the whole set gives the same data.
  write_dataset(original, folder_ / "whole");
  ReadOptions options;
  options.max_frames = 3;
  options.max_robots = 2;
  expect_same_dataset(read_dataset(folder_ / "whole", options), cut);

  // Counts beyond the data keep everything; counts below 1 are rejected.
  expect_same_dataset(slice(original, 1000, 1000), original);
  EXPECT_THROW(slice(original, 0, 1), std::invalid_argument);
  EXPECT_THROW(slice(original, 1, 0), std::invalid_argument);
}

// --- Result files ---

TEST_F(DatasetFilesTest, TrajectoryRoundTripIsExact) {
  const std::vector<Eigen::Isometry3d> poses = random_dataset().robots[2].groundtruth;
  const std::filesystem::path file = folder_ / "robot_02.kitti";
  write_trajectory_kitti(file, poses);
  expect_same_poses(read_trajectory_kitti(file), poses);

  write_trajectory_kitti(file, {});
  EXPECT_TRUE(read_trajectory_kitti(file).empty());
}

TEST_F(DatasetFilesTest, TrajectoryReadErrors) {
  EXPECT_THAT(dataset_error_message([&] { read_trajectory_kitti(folder_ / "missing.kitti"); }),
              HasSubstr("missing.kitti: file not found"));
  write_text(folder_ / "bad.kitti", "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 y\n");
  EXPECT_THAT(dataset_error_message([&] { read_trajectory_kitti(folder_ / "bad.kitti"); }),
              HasSubstr("bad.kitti:2: entry 12 'y' is not a number"));
}

TEST_F(DatasetFilesTest, ObjectsCsvRoundTripIsExactAndSorted) {
  std::vector<ObjectEstimate> objects(3);
  objects[0].id = 42;
  objects[0].p_world = {1.0 / 3.0, -2.5, 1e-300};
  Eigen::Matrix3d square_root;
  square_root << 1.1, 0.2, 0.3, 0, 2.0 / 3.0, 0.1, 0, 0, 0.7;
  objects[0].covariance = square_root.transpose() * square_root;
  objects[1].id = -5;
  objects[1].p_world = {10, 20, 30};
  objects[2].id = 7;
  objects[2].covariance = Eigen::Matrix3d::Identity() * 0.1;

  const std::filesystem::path file = folder_ / "objects.csv";
  write_objects_csv(file, objects);
  const std::string text = read_text(file);
  EXPECT_EQ(text.substr(0, text.find('\n')), "id,x,y,z,cxx,cxy,cxz,cyy,cyz,czz");
  EXPECT_THAT(text, HasSubstr("\n-5,10,20,30,1,0,0,1,0,1\n7,"));

  const std::vector<ObjectEstimate> read_back = read_objects_csv(file);
  ASSERT_EQ(read_back.size(), 3u);
  const std::vector<std::size_t> expected_order = {1, 2, 0};
  for (std::size_t index = 0; index < read_back.size(); ++index) {
    const ObjectEstimate& expected = objects[expected_order[index]];
    EXPECT_EQ(read_back[index].id, expected.id);
    EXPECT_EQ(read_back[index].p_world, expected.p_world);
    EXPECT_EQ(read_back[index].covariance, expected.covariance);
  }
}

TEST_F(DatasetFilesTest, ObjectsCsvReadErrors) {
  const std::filesystem::path file = folder_ / "estimates.csv";
  write_text(file, "id,x,y,z\n1,2,3,4\n");
  EXPECT_THAT(dataset_error_message([&] { read_objects_csv(file); }),
              HasSubstr("estimates.csv:1: expected the header 'id,x,y,z,cxx,cxy,cxz,cyy,cyz,czz'"));
  write_text(file, "id,x,y,z,cxx,cxy,cxz,cyy,cyz,czz\n1,0,0,0,1,0,0,1,0,1\n1,0,0,0,1,0,0,1,0,1\n");
  EXPECT_THAT(dataset_error_message([&] { read_objects_csv(file); }),
              HasSubstr("estimates.csv:3: duplicate id 1"));
  write_text(file, "id,x,y,z,cxx,cxy,cxz,cyy,cyz,czz\n1,0,0,0,1,0,0,1,0\n");
  EXPECT_THAT(dataset_error_message([&] { read_objects_csv(file); }),
              HasSubstr("estimates.csv:2: expected 10 comma-separated fields, found 9"));
  write_text(file, "id,x,y,z,cxx,cxy,cxz,cyy,cyz,czz\n1,0,0,0,1,0,0,1,0,nan\n");
  EXPECT_THAT(dataset_error_message([&] { read_objects_csv(file); }),
              HasSubstr("estimates.csv:2: czz 'nan' is not finite"));
}

TEST_F(DatasetFilesTest, AtomicWriteReplacesAndLeavesNoTemporaryFile) {
  const std::filesystem::path file = folder_ / "status.json";
  write_file_atomically(file, "first");
  write_file_atomically(file, "second, longer content\n");
  EXPECT_EQ(read_text(file), "second, longer content\n");
  std::vector<std::filesystem::path> entries;
  for (const auto& entry : std::filesystem::directory_iterator(folder_)) {
    entries.push_back(entry.path().filename());
  }
  EXPECT_EQ(entries, std::vector<std::filesystem::path>{"status.json"});

  EXPECT_THROW(write_file_atomically(folder_ / "no_such_folder" / "file.txt", "x"),
               std::runtime_error);
  EXPECT_FALSE(std::filesystem::exists(folder_ / "no_such_folder"));
}

}  // namespace
}  // namespace concord::dataset
