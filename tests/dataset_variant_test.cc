// Private object ids, unknown start poses, detector classes and false detections in the dataset
// layout and the simulator (issue 11, step 1): reading, writing, errors, the sensor view that never
// carries the ground truth, and `make_variant`.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <string>

#include "concord/dataset/dataset.h"
#include "sim/simulator.h"

namespace concord::dataset {
namespace {

using ::testing::HasSubstr;

class DatasetVariantTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const ::testing::TestInfo* info = ::testing::UnitTest::GetInstance()->current_test_info();
    folder_ = std::filesystem::path(::testing::TempDir()) /
              ("concord_variant_" + std::string(info->name()) + "_" + std::to_string(::getpid()));
    std::filesystem::remove_all(folder_);
    std::filesystem::create_directories(folder_);
  }
  void TearDown() override { std::filesystem::remove_all(folder_); }

  static void write_text(const std::filesystem::path& file, const std::string& text) {
    std::ofstream stream(file, std::ios::binary);
    stream << text;
  }

  /// A small simulated team with classes and false detections.
  static Dataset small_simulation(bool private_ids, bool unknown_start) {
    sim::SimulationOptions options;
    options.robots = 3;
    options.frames = 60;
    options.objects = 40;
    options.points_per_frame = 0;
    options.classes = 4;
    options.false_detection_rate = 0.05;
    options.private_ids = private_ids;
    options.unknown_start = unknown_start;
    return sim::simulate(options);
  }

  std::filesystem::path folder_;
};

TEST_F(DatasetVariantTest, DefaultsAreGlobalIdsAndKnownStarts) {
  const Dataset data = small_simulation(false, false);
  EXPECT_EQ(data.object_ids, ObjectIds::kGlobal);
  EXPECT_EQ(data.start_poses, StartPoses::kKnown);
  const TeamInputs inputs = sensor_inputs(data);
  ASSERT_TRUE(inputs.robots[1].T_world_body_start.has_value());
  EXPECT_TRUE(inputs.robots[1].T_world_body_start->isApprox(data.robots[1].groundtruth.front()));
}

TEST_F(DatasetVariantTest, UnknownStartsGiveNoStartPoseToTheRobots) {
  const Dataset data = small_simulation(false, true);
  EXPECT_EQ(data.start_poses, StartPoses::kUnknown);
  const TeamInputs inputs = sensor_inputs(data);
  for (const RobotInputs& robot : inputs.robots) EXPECT_FALSE(robot.T_world_body_start);
  // The ground truth stays in the world frame.
  const Dataset known = small_simulation(false, false);
  EXPECT_TRUE(data.robots[2].groundtruth[10].isApprox(known.robots[2].groundtruth[10]));
}

TEST_F(DatasetVariantTest, PrivateIdsAreRenumberedPerRobotWithATruthMap) {
  const Dataset global = small_simulation(false, false);
  const Dataset variant = make_variant(global, true, false);
  EXPECT_EQ(variant.object_ids, ObjectIds::kPrivate);
  for (std::size_t r = 0; r < global.robots.size(); ++r) {
    const RobotData& before = global.robots[r];
    const RobotData& after = variant.robots[r];
    ASSERT_TRUE(after.has_object_truth_ids);
    LandmarkId largest = -1;
    for (std::size_t k = 0; k < before.objects.size(); ++k) {
      ASSERT_EQ(before.objects[k].size(), after.objects[k].size());
      for (std::size_t n = 0; n < before.objects[k].size(); ++n) {
        const LandmarkId global_id = before.objects[k][n].id;
        const LandmarkId private_id = after.objects[k][n].id;
        EXPECT_EQ(before.objects[k][n].uv, after.objects[k][n].uv);
        // Ids are numbered in the order of first sight: a new id is the next number.
        if (private_id > largest) {
          EXPECT_EQ(private_id, largest + 1);
          largest = private_id;
        }
        const LandmarkId truth = after.object_truth_ids.at(private_id);
        if (global.objects_groundtruth.contains(global_id)) {
          EXPECT_EQ(truth, global_id);
        } else {
          EXPECT_EQ(truth, kNoTruthId);  // a false detection
          EXPECT_GE(global_id, sim::kPhantomIdBase);
        }
      }
    }
  }
  // Robot 0's 7 and robot 1's 7 are (generally) different objects.
  EXPECT_NE(variant.robots[0].object_truth_ids.at(7), variant.robots[1].object_truth_ids.at(7));
}

TEST_F(DatasetVariantTest, TheSensorViewHoldsNoTruth) {
  const Dataset data = small_simulation(true, true);
  const TeamInputs inputs = sensor_inputs(data);
  // What a robot may use: measurements and classes; TeamInputs has no field for ground truth or
  // truth ids at all (checked here by the sizes of what it does carry).
  ASSERT_EQ(inputs.robots.size(), data.robots.size());
  EXPECT_EQ(inputs.object_ids, ObjectIds::kPrivate);
  EXPECT_EQ(inputs.robots[0].num_frames(), data.robots[0].num_frames());
  EXPECT_TRUE(inputs.robots[0].has_object_classes);
  for (std::size_t k = 0; k < inputs.robots[0].objects.size(); ++k) {
    EXPECT_EQ(inputs.robots[0].objects[k].size(), inputs.robots[0].object_classes[k].size());
  }
}

TEST_F(DatasetVariantTest, WriteThenReadKeepsFlagsClassesAndTruthIds) {
  const Dataset data = small_simulation(true, true);
  write_dataset(data, folder_ / "set");
  EXPECT_TRUE(std::filesystem::exists(folder_ / "set" / "robot_01" / "object_ids_truth.csv"));
  const Dataset read = read_dataset(folder_ / "set");
  EXPECT_EQ(read.object_ids, ObjectIds::kPrivate);
  EXPECT_EQ(read.start_poses, StartPoses::kUnknown);
  for (std::size_t r = 0; r < data.robots.size(); ++r) {
    EXPECT_TRUE(read.robots[r].has_object_classes);
    EXPECT_EQ(read.robots[r].object_classes, data.robots[r].object_classes);
    EXPECT_EQ(read.robots[r].object_truth_ids, data.robots[r].object_truth_ids);
  }
  // A slice keeps the flags, classes and truth ids.
  const Dataset cut = slice(read, 20, 2);
  EXPECT_EQ(cut.object_ids, ObjectIds::kPrivate);
  EXPECT_EQ(cut.robots[1].object_classes.size(), 20u);
  EXPECT_EQ(cut.robots[1].object_truth_ids, data.robots[1].object_truth_ids);
}

TEST_F(DatasetVariantTest, ClassesAndFalseDetectionsAreAsConfigured) {
  const Dataset data = small_simulation(false, false);
  long long detections = 0, false_detections = 0;
  std::map<LandmarkId, int> class_of;
  for (const RobotData& robot : data.robots) {
    for (std::size_t k = 0; k < robot.objects.size(); ++k) {
      for (std::size_t n = 0; n < robot.objects[k].size(); ++n) {
        ++detections;
        const LandmarkId id = robot.objects[k][n].id;
        const int object_class = robot.object_classes[k][n];
        EXPECT_GE(object_class, 0);
        EXPECT_LT(object_class, 4);
        if (!data.objects_groundtruth.contains(id)) ++false_detections;
        // An object keeps its class.
        const auto [it, inserted] = class_of.emplace(id, object_class);
        EXPECT_EQ(it->second, object_class);
      }
    }
  }
  const double rate = static_cast<double>(false_detections) / static_cast<double>(detections);
  EXPECT_GT(rate, 0.02);
  EXPECT_LT(rate, 0.09);
  // Classes and false detections change nothing else: the true detections are the same.
  sim::SimulationOptions plain;
  plain.robots = 3;
  plain.frames = 60;
  plain.objects = 40;
  plain.points_per_frame = 0;
  const Dataset without = sim::simulate(plain);
  for (std::size_t r = 0; r < data.robots.size(); ++r) {
    for (std::size_t k = 0; k < data.robots[r].objects.size(); ++k) {
      std::vector<StereoObservation> real;
      for (const auto& observation : data.robots[r].objects[k]) {
        if (data.objects_groundtruth.contains(observation.id)) real.push_back(observation);
      }
      ASSERT_EQ(real.size(), without.robots[r].objects[k].size());
      for (std::size_t n = 0; n < real.size(); ++n) {
        EXPECT_EQ(real[n].id, without.robots[r].objects[k][n].id);
        EXPECT_EQ(real[n].uv, without.robots[r].objects[k][n].uv);
      }
    }
  }
}

TEST_F(DatasetVariantTest, BadFlagsAndFilesAreNamed) {
  const Dataset data = small_simulation(true, false);
  write_dataset(data, folder_ / "set");
  const auto error_of = [&] {
    try {
      read_dataset(folder_ / "set");
    } catch (const DatasetError& error) {
      return std::string(error.what());
    }
    return std::string("no error");
  };
  const std::filesystem::path description = folder_ / "set" / "dataset.json";
  std::ifstream stream(description);
  const std::string text((std::istreambuf_iterator<char>(stream)), {});
  write_text(description, std::string(text).replace(text.find("\"private\""), 9, "\"secret\""));
  EXPECT_THAT(error_of(),
              HasSubstr("dataset.json: \"object_ids\" must be \"global\" or \"private\""));
  write_text(description, std::string(text).replace(text.find("\"known\""), 7, "7"));
  EXPECT_THAT(error_of(), HasSubstr("\"start_poses\" must be \"known\" or \"unknown\""));
  write_text(description, text);

  const std::filesystem::path truth = folder_ / "set" / "robot_01" / "object_ids_truth.csv";
  write_text(truth, "id,truth_id\n0,3\n0,4\n");
  EXPECT_THAT(error_of(), HasSubstr("object_ids_truth.csv:3: duplicate id 0"));
  write_text(truth, "id,truth\n");
  EXPECT_THAT(error_of(), HasSubstr("object_ids_truth.csv:1: expected the header 'id,truth_id'"));
  write_text(truth, "id,truth_id\n0,-2\n");
  EXPECT_THAT(error_of(), HasSubstr("object_ids_truth.csv:2: truth_id -2 must be >= -1"));
  write_text(truth, "id,truth_id\n");

  const std::filesystem::path objects = folder_ / "set" / "robot_00" / "objects.csv";
  write_text(objects, "frame,id,u_left,v_left,u_right,v_right,class\n0,1,0.1,0.1,0,0.1,-3\n");
  EXPECT_THAT(error_of(), HasSubstr("objects.csv:2: class -3 must be an integer >= 0"));
  write_text(objects, "frame,id,u_left,v_left,u_right,v_right,kind\n");
  EXPECT_THAT(
      error_of(),
      HasSubstr("(or with optional columns: 'frame,id,u_left,v_left,u_right,v_right,class')"));
}

TEST_F(DatasetVariantTest, SimulatorOptionsAreValidatedAndRecorded) {
  sim::SimulationOptions options;
  options.classes = -1;
  options.false_detection_rate = 0.7;
  const auto problems = options.validate();
  ASSERT_EQ(problems.size(), 2u);
  EXPECT_THAT(problems[0], HasSubstr("--classes = -1"));
  EXPECT_THAT(problems[1], HasSubstr("--false-detections = 0.7"));
  options = {};
  options.private_ids = true;
  const std::string json = sim::to_json(options);
  EXPECT_THAT(json, HasSubstr("\"private_ids\": true"));
  EXPECT_THAT(json, HasSubstr("\"false_detection_rate\""));
}

}  // namespace
}  // namespace concord::dataset
