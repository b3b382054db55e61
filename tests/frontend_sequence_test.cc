// Image-sequence and calibration readers (EuRoC ASL, KITTI odometry), detections tables and
// front-end option files, with their error cases: every error names the file and what is wrong.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>
#include <opencv2/imgcodecs.hpp>

#include "concord/frontend/detections.h"
#include "concord/frontend/frontend_options_file.h"
#include "concord/frontend/rectifier.h"
#include "concord/frontend/sequence.h"
#include "frontend_test_support.h"

namespace concord::frontend {
namespace {

namespace fs = std::filesystem;
using ::testing::AllOf;
using ::testing::HasSubstr;

void write_text(const fs::path& file, const std::string& text) {
  fs::create_directories(file.parent_path());
  std::ofstream(file) << text;
}

std::string read_text(const fs::path& file) {
  std::ifstream stream(file);
  return std::string(std::istreambuf_iterator<char>(stream), std::istreambuf_iterator<char>());
}

/// The error message of `action`, or "" if it did not throw FrontendError.
template <typename Action>
std::string error_of(Action&& action) {
  try {
    action();
  } catch (const FrontendError& error) {
    return error.what();
  }
  return "";
}

/// A tiny KITTI-layout sequence of `frames` 64x48 pairs with baseline 0.5 m.
fs::path make_kitti_sequence(const std::string& name, int frames) {
  const fs::path folder = testing::temporary_folder(name);
  write_text(folder / "calib.txt",
             "P0: 50 0 32 0 0 50 24 0 0 0 1 0\n"
             "P1: 50 0 32 -25 0 50 24 0 0 0 1 0\n"
             "P2: 50 0 32 0 0 50 24 0 0 0 1 0\n");
  std::string times;
  const cv::Mat image(48, 64, CV_8UC1, cv::Scalar(100));
  fs::create_directories(folder / "image_0");
  fs::create_directories(folder / "image_1");
  for (int frame = 0; frame < frames; ++frame) {
    char file[32];
    std::snprintf(file, sizeof file, "%06d.png", frame);
    cv::imwrite((folder / "image_0" / file).string(), image);
    cv::imwrite((folder / "image_1" / file).string(), image);
    times += std::to_string(0.1 * frame) + "\n";
  }
  write_text(folder / "times.txt", times);
  return folder;
}

/// A copy of the repository's EuRoC frames that a test may break.
fs::path copy_euroc(const std::string& name) {
  const fs::path folder = testing::temporary_folder(name);
  fs::copy(testing::euroc_frames(), folder, fs::copy_options::recursive);
  return folder;
}

TEST(FrontendSequence, ReadsTheEurocFramesWithCalibrationAndGroundTruth) {
  const StereoSequence sequence = read_stereo_sequence(testing::euroc_frames());
  EXPECT_EQ(sequence.layout, SequenceLayout::kEuroc);
  ASSERT_EQ(sequence.num_frames(), 4);
  EXPECT_NEAR(sequence.timestamps[1] - sequence.timestamps[0], 0.65, 1e-6);
  EXPECT_EQ(sequence.rig.left.width, 752);
  EXPECT_EQ(sequence.rig.left.height, 480);
  EXPECT_DOUBLE_EQ(sequence.rig.left.fx, 458.654);
  EXPECT_DOUBLE_EQ(sequence.rig.right.distortion(0), -0.28368365);
  // T_cam0_cam1 from the two T_BS: the right camera about 11 cm along the left camera's x.
  EXPECT_NEAR(sequence.rig.T_cam0_cam1.translation().x(), 0.110, 0.001);
  EXPECT_NEAR(sequence.rig.T_cam0_cam1.translation().norm(), 0.110, 0.001);
  EXPECT_FALSE(sequence.rig.rectified);
  ASSERT_TRUE(sequence.groundtruth.has_value());
  ASSERT_EQ(sequence.groundtruth->size(), 4u);
  EXPECT_NEAR(sequence.groundtruth->front().translation().x(), 0.878895, 1e-9);
  for (const fs::path& image : sequence.right_images) EXPECT_TRUE(fs::exists(image));
}

TEST(FrontendSequence, RectificationOfTheEurocRigGivesOneCameraAndAHorizontalBaseline) {
  const StereoSequence sequence = read_stereo_sequence(testing::euroc_frames());
  const StereoRectifier rectifier(sequence.rig);
  const StereoCamera& camera = rectifier.camera();
  EXPECT_GT(camera.K(0, 0), 400.0);
  EXPECT_DOUBLE_EQ(camera.K(0, 0), camera.K(1, 1));
  EXPECT_NEAR(camera.baseline(), 0.110, 0.001);
  EXPECT_TRUE(camera.T_cam0_cam1.linear().isIdentity(1e-12));
  EXPECT_DOUBLE_EQ(camera.T_cam0_cam1.translation().y(), 0.0);
  // The rectified left frame is the raw one turned by a small rotation; the body is where it was.
  const Eigen::Matrix3d turn =
      camera.T_cam0_body.linear() * sequence.rig.T_cam0_body.linear().transpose();
  EXPECT_LT(Eigen::AngleAxisd(turn).angle(), 0.05);
  EXPECT_TRUE(camera.T_cam0_body.inverse().translation().isApprox(
      sequence.rig.T_cam0_body.inverse().translation(), 1e-9));
  cv::Mat left, right;
  rectifier.rectify(cv::imread(sequence.left_images[0].string(), cv::IMREAD_UNCHANGED),
                    cv::imread(sequence.right_images[0].string(), cv::IMREAD_UNCHANGED), left,
                    right);
  EXPECT_EQ(left.size(), cv::Size(752, 480));
  EXPECT_EQ(left.type(), CV_8UC1);
  EXPECT_THAT(error_of([&] { rectifier.rectify(cv::Mat(10, 10, CV_8UC1), left, left, right); }),
              HasSubstr("is 10x10, the calibration's 752x480"));
}

TEST(FrontendSequence, ReadsAKittiSequence) {
  const fs::path folder = make_kitti_sequence("kitti_ok", 3);
  const StereoSequence sequence = read_stereo_sequence(folder);
  EXPECT_EQ(sequence.layout, SequenceLayout::kKitti);
  EXPECT_EQ(sequence.num_frames(), 3);
  EXPECT_TRUE(sequence.rig.rectified);
  EXPECT_EQ(sequence.rig.left.width, 64);
  EXPECT_DOUBLE_EQ(sequence.rig.T_cam0_cam1.translation().x(), 0.5);
  EXPECT_FALSE(sequence.groundtruth.has_value());
  EXPECT_EQ(read_stereo_sequence(folder, {.max_frames = 2}).num_frames(), 2);
  const StereoRectifier rectifier(sequence.rig);  // pass-through
  EXPECT_DOUBLE_EQ(rectifier.camera().K(0, 2), 32.0);
  EXPECT_DOUBLE_EQ(rectifier.camera().baseline(), 0.5);
}

TEST(FrontendSequence, KittiErrorsNameTheFile) {
  {
    const fs::path folder = make_kitti_sequence("kitti_missing_image", 3);
    fs::remove(folder / "image_1" / "000001.png");
    EXPECT_THAT(error_of([&] { (void)read_stereo_sequence(folder); }),
                AllOf(HasSubstr("image_1/000001.png"), HasSubstr("image not found")));
  }
  {
    const fs::path folder = make_kitti_sequence("kitti_times", 3);
    write_text(folder / "times.txt", "0\n0.1\n");
    EXPECT_THAT(error_of([&] { (void)read_stereo_sequence(folder); }),
                AllOf(HasSubstr("times.txt"), HasSubstr("has 2 times but"), HasSubstr("3 images")));
    write_text(folder / "times.txt", "0\n0.1\n0.1\n");
    EXPECT_THAT(error_of([&] { (void)read_stereo_sequence(folder); }),
                AllOf(HasSubstr("times.txt:3"), HasSubstr("must increase")));
  }
  {
    const fs::path folder = make_kitti_sequence("kitti_calibration", 2);
    write_text(folder / "calib.txt", "P0: 50 0 32 0 0 50 24 0 0 0 1 0\n");
    EXPECT_THAT(error_of([&] { (void)read_stereo_sequence(folder); }),
                AllOf(HasSubstr("calib.txt"), HasSubstr("missing P1")));
    write_text(folder / "calib.txt",
               "P0: 50 0 32 0 0 50 24 0 0 0 1 0\nP1: 50 0 32 -25 0 50 24 zero 0 0 1 0\n");
    EXPECT_THAT(error_of([&] { (void)read_stereo_sequence(folder); }),
                AllOf(HasSubstr("calib.txt:2"), HasSubstr("'zero' is not a finite number")));
    write_text(folder / "calib.txt",
               "P0: 50 0 32 0 0 50 24 0 0 0 1 0\nP1: 50 0 32 0 0 50 24 0 0 0 1 0\n");
    EXPECT_THAT(error_of([&] { (void)read_stereo_sequence(folder); }),
                AllOf(HasSubstr("calib.txt"), HasSubstr("baseline is 0 m")));
    write_text(folder / "calib.txt",
               "P0: -50 0 32 0 0 50 24 0 0 0 1 0\nP1: -50 0 32 25 0 50 24 0 0 0 1 0\n");
    EXPECT_THAT(error_of([&] { (void)read_stereo_sequence(folder); }),
                AllOf(HasSubstr("calib.txt"), HasSubstr("focal lengths must be positive")));
  }
  {
    const fs::path folder = make_kitti_sequence("kitti_poses", 2);
    write_text(folder / "poses.txt", "1 0 0 0 0 1 0 0 0 0 1 0\n");
    EXPECT_THAT(error_of([&] { (void)read_stereo_sequence(folder); }),
                AllOf(HasSubstr("poses.txt"), HasSubstr("has 1 poses but times.txt has 2")));
  }
  EXPECT_THAT(error_of([&] { (void)read_stereo_sequence(testing::temporary_folder("not_a_sequence")); }),
              HasSubstr("not a stereo sequence"));
}

TEST(FrontendSequence, EurocErrorsNameTheFile) {
  {
    const fs::path folder = copy_euroc("euroc_timestamps");
    const fs::path list = folder / "mav0/cam1/data.csv";
    std::string text = read_text(list);
    text.replace(text.find("1403715273912143104,"), 20, "1403715273912153104,");
    write_text(list, text);
    EXPECT_THAT(error_of([&] { (void)read_stereo_sequence(folder); }),
                AllOf(HasSubstr("cam1/data.csv"), HasSubstr("image 2"),
                      HasSubstr("mismatched by 10000 ns")));
  }
  {
    const fs::path folder = copy_euroc("euroc_missing_image");
    fs::remove(folder / "mav0/cam0/data/1403715274562142976.png");
    EXPECT_THAT(error_of([&] { (void)read_stereo_sequence(folder); }),
                AllOf(HasSubstr("cam0/data.csv:4"), HasSubstr("image not found"),
                      HasSubstr("1403715274562142976.png")));
  }
  {
    const fs::path folder = copy_euroc("euroc_count");
    const fs::path list = folder / "mav0/cam1/data.csv";
    const std::string text = read_text(list);
    write_text(list, text.substr(0, text.find("1403715275212143104")));
    EXPECT_THAT(
        error_of([&] { (void)read_stereo_sequence(folder); }),
        AllOf(HasSubstr("cam1/data.csv"), HasSubstr("lists 3 images"), HasSubstr("lists 4")));
  }
  {
    const fs::path folder = copy_euroc("euroc_distortion");
    const fs::path yaml = folder / "mav0/cam0/sensor.yaml";
    std::string text = read_text(yaml);
    text.replace(text.find("radial-tangential"), 17, "equidistant");
    write_text(yaml, text);
    EXPECT_THAT(error_of([&] { (void)read_stereo_sequence(folder); }),
                AllOf(HasSubstr("cam0/sensor.yaml"), HasSubstr("distortion_model"),
                      HasSubstr("equidistant")));
  }
  {
    const fs::path folder = copy_euroc("euroc_intrinsics");
    const fs::path yaml = folder / "mav0/cam1/sensor.yaml";
    std::string text = read_text(yaml);
    text.replace(text.find("[457.587, 456.134, 379.999, 255.238]"), 36, "[457.587, 456.134]");
    write_text(yaml, text);
    EXPECT_THAT(error_of([&] { (void)read_stereo_sequence(folder); }),
                AllOf(HasSubstr("cam1/sensor.yaml"), HasSubstr("intrinsics"),
                      HasSubstr("sequence of 4 numbers")));
  }
  {
    // The right camera moved on top of the left one: not a stereo pair.
    const fs::path folder = copy_euroc("euroc_rig");
    const fs::path yaml = folder / "mav0/cam1/sensor.yaml";
    std::string text = read_text(yaml);
    text.replace(text.find("0.0453689425024"), 15, "-0.064676986768");
    text.replace(text.find("-0.0198435579556"), 16, "-0.0216401454975");
    text.replace(text.find("0.00786212447038"), 16, "0.00981073058949");
    write_text(yaml, text);
    EXPECT_THAT(error_of([&] { (void)read_stereo_sequence(folder); }),
                AllOf(HasSubstr("unusable stereo calibration"), HasSubstr("baseline")));
  }
}

TEST(FrontendDetections, ReadsPerFrameListsAndNamesBadRows) {
  const fs::path folder = testing::temporary_folder("detections");
  const fs::path file = folder / "detections.csv";
  write_text(file,
             "frame,track_id,class,x_min,y_min,x_max,y_max\n"
             "0,7,car,10,20,30,40\n"
             "2,7,car,11,21,31,41\n"
             "2,9,person,1.5,2.5,3.5,4.5\n");
  const auto detections = read_detections(file, 3);
  ASSERT_EQ(detections.size(), 3u);
  EXPECT_EQ(detections[0].size(), 1u);
  EXPECT_TRUE(detections[1].empty());
  ASSERT_EQ(detections[2].size(), 2u);
  EXPECT_EQ(detections[2][1].class_name, "person");
  EXPECT_DOUBLE_EQ(detections[2][1].centre_x(), 2.5);
  // Writing and reading give the same table.
  write_text(file, format_detections(detections));
  EXPECT_EQ(read_detections(file, 3)[2][0].x_max, 31.0);

  const auto problem = [&](const std::string& text, int frames = 3) {
    write_text(file, text);
    return error_of([&] { (void)read_detections(file, frames); });
  };
  const std::string header = "frame,track_id,class,x_min,y_min,x_max,y_max\n";
  EXPECT_THAT(problem("frame,id,x\n"), AllOf(HasSubstr("detections.csv:1"), HasSubstr("header")));
  EXPECT_THAT(problem(header + "3,1,car,0,0,1,1\n"),
              AllOf(HasSubstr("detections.csv:2"), HasSubstr("frame 3 is outside [0, 2]")));
  EXPECT_THAT(problem(header + "0,1,car,5,0,4,1\n"),
              AllOf(HasSubstr("detections.csv:2"), HasSubstr("empty box")));
  EXPECT_THAT(problem(header + "0,1,car,0,0,1,1\n0,1,car,2,2,3,3\n"),
              AllOf(HasSubstr("detections.csv:3"), HasSubstr("detected twice")));
  EXPECT_THAT(problem(header + "0,1,car,0,0,x,1\n"),
              AllOf(HasSubstr("detections.csv:2"), HasSubstr("x_max 'x'")));
  EXPECT_THAT(problem(header + "0,1,car,0,0,1\n"), HasSubstr("expected 7 comma-separated fields"));
  // A sequence cut short keeps the detections of its frames.
  write_text(file, header + "0,1,car,0,0,1,1\n5,1,car,0,0,1,1\n");
  EXPECT_EQ(read_detections(file, 2, true).size(), 2u);
}

TEST(FrontendClasses, NamesAreNumberedByTheSetOfNamesWhateverTheirOrder) {
  const ClassNumbering names({"person", "car", "bike", "car"});
  EXPECT_EQ(names.number("bike"), 0);
  EXPECT_EQ(names.number("car"), 1);
  EXPECT_EQ(names.number("person"), 2);
  EXPECT_EQ(names.number("truck"), std::nullopt);
  EXPECT_EQ(names.numbered_names(), (std::vector<std::string>{"bike", "car", "person"}));
  const ClassNumbering reordered({"car", "bike", "person"});
  for (const std::string name : {"bike", "car", "person"})
    EXPECT_EQ(reordered.number(name), names.number(name)) << name;

  // All numbers: the numbers themselves (up to kMaxClassNumber).
  const ClassNumbering numbers({"17", "3", "1000000"});
  EXPECT_EQ(numbers.number("17"), 17);
  EXPECT_EQ(numbers.number("1000000"), 1000000);
  EXPECT_EQ(numbers.number("4"), std::nullopt);
  EXPECT_TRUE(numbers.numbered_names().empty());
  // A name that is not a number (or too large a number) numbers them all by position.
  const ClassNumbering mixed({"17", "3", "1000001"});
  EXPECT_EQ(mixed.number("1000001"), 0);
  EXPECT_EQ(mixed.number("17"), 1);
  EXPECT_EQ(mixed.number("3"), 2);
  EXPECT_THAT(error_of([] { (void)ClassNumbering({"car", ""}); }), HasSubstr("empty class name"));
}

TEST(FrontendClasses, ARobotNumbersItsDetectionsByTheTeamsListOrByTheirNumbers) {
  const auto detections = [](std::vector<std::string> names) {
    std::vector<std::vector<Detection>> frames(2);
    for (std::size_t n = 0; n < names.size(); ++n) {
      Detection detection;
      detection.class_name = names[n];
      frames[n % 2].push_back(detection);
    }
    return frames;
  };
  // The team's list: this robot's detections use two of its three names; numbered as the team.
  const auto listed = robot_class_numbering(detections({"person", "car", "person"}),
                                            {"person", "car", "bike"}, "d.csv");
  ASSERT_TRUE(listed);
  EXPECT_EQ(listed->number("car"), 1);
  EXPECT_EQ(listed->number("person"), 2);
  EXPECT_THAT(error_of([&] {
                (void)robot_class_numbering(detections({"car", "truck"}), {"car", "bike"},
                                            "d.csv");
              }),
              AllOf(HasSubstr("d.csv"), HasSubstr("class 'truck' is not one of the team's")));
  // No list: numbers pass as themselves; names cannot be numbered alike without the list.
  const auto numbered = robot_class_numbering(detections({"4", "12"}), {}, "d.csv");
  ASSERT_TRUE(numbered);
  EXPECT_EQ(numbered->number("12"), 12);
  EXPECT_FALSE(robot_class_numbering(detections({"4", "car"}), {}, "d.csv"));
  EXPECT_FALSE(robot_class_numbering(detections({}), {}, "d.csv"));
}

TEST(FrontendOptionsFile, ReadsWritesAndNamesEveryProblem) {
  const FrontendOptions options = parse_frontend_options(
      "tracker: {target_features: 300}\nodometry: {pixel_sigma: 0.3}\n", "x");
  EXPECT_EQ(options.tracker.target_features, 300);
  EXPECT_DOUBLE_EQ(options.odometry.pixel_sigma, 0.3);
  EXPECT_EQ(options.objects.min_region_size, ObjectOptions{}.min_region_size);
  const FrontendOptions again = parse_frontend_options(to_yaml(options), "again");
  EXPECT_EQ(to_yaml(again), to_yaml(options));

  const std::string message = error_of([] {
    (void)parse_frontend_options(
        "tracker: {target_feature: 3, klt_window: 4, grid_rows: many}\nodometer: {}\n", "fe.yaml");
  });
  EXPECT_THAT(message, AllOf(HasSubstr("fe.yaml"), HasSubstr("unknown key tracker.target_feature"),
                             HasSubstr("tracker.grid_rows = 'many': expected an integer"),
                             HasSubstr("unknown key odometer")));
  EXPECT_THAT(error_of([] { (void)parse_frontend_options("tracker: {klt_window: 4}\n", "fe.yaml"); }),
              HasSubstr("klt_window = 4"));
}

}  // namespace
}  // namespace concord::frontend
