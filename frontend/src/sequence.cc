#include "concord/frontend/sequence.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <map>
#include <opencv2/imgcodecs.hpp>

#include "concord/dataset/result_io.h"
#include "text_lines.h"

namespace concord::frontend {

namespace fs = std::filesystem;

namespace {

using text::fail_in_file;

/// A number in its shortest exact text form, for messages.
std::string to_text(double value) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  return std::string(buffer, result.ptr);
}

bool finite(const Eigen::Isometry3d& pose) { return pose.matrix().allFinite(); }

void check_rig(const StereoRig& rig, const fs::path& source) {
  const std::vector<std::string> problems = rig.problems();
  if (problems.empty()) return;
  std::string message = "unusable stereo calibration:";
  for (const std::string& problem : problems) message += " " + problem;
  fail_in_file(source, message);
}

// ------------------------------------------------------------------------------------------------
// EuRoC ASL

/// A sensor.yaml file: yaml-cpp does not accept OpenCV's "%YAML:1.0" directive, so it is dropped.
YAML::Node load_sensor_yaml(const fs::path& file) {
  std::string content = text::read_text(file);
  if (content.starts_with("%YAML:")) content.erase(0, content.find('\n'));
  try {
    YAML::Node root = YAML::Load(content);
    if (!root.IsMap()) fail_in_file(file, "expected a map of sensor settings");
    return root;
  } catch (const YAML::ParserException& error) {
    throw FrontendError(file.string() + ":" + std::to_string(error.mark.line + 1) +
                        ": invalid YAML: " + error.msg);
  }
}

/// `count` numbers at `key` (a sequence), FrontendError naming file and key otherwise.
std::vector<double> yaml_numbers(const YAML::Node& node, const std::string& key, std::size_t count,
                                 const fs::path& file) {
  const YAML::Node value = node[key];
  const std::string expected = "expected a sequence of " + std::to_string(count) + " numbers";
  if (!value) fail_in_file(file, "missing key '" + key + "'");
  if (!value.IsSequence() || value.size() != count) fail_in_file(file, key + ": " + expected);
  std::vector<double> numbers;
  for (const YAML::Node& item : value) {
    try {
      numbers.push_back(item.as<double>());
    } catch (const YAML::Exception&) {
      fail_in_file(file, key + ": " + expected);
    }
    if (!std::isfinite(numbers.back())) fail_in_file(file, key + ": numbers must be finite");
  }
  return numbers;
}

Eigen::Isometry3d yaml_transform(const YAML::Node& node, const std::string& key,
                                 const fs::path& file) {
  const YAML::Node value = node[key];
  if (!value || !value.IsMap()) fail_in_file(file, "missing key '" + key + "' (rows, cols, data)");
  const std::vector<double> data = yaml_numbers(value, "data", 16, file);
  Eigen::Matrix4d matrix;
  for (int index = 0; index < 16; ++index) matrix(index / 4, index % 4) = data[index];
  if (!matrix.row(3).isApprox(Eigen::RowVector4d(0, 0, 0, 1), 1e-9)) {
    fail_in_file(file, key + ": last row must be [0, 0, 0, 1]");
  }
  const Eigen::Matrix3d rotation = matrix.topLeftCorner<3, 3>();
  if ((rotation.transpose() * rotation - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() >
          1e-3 ||
      rotation.determinant() < 0.0) {
    fail_in_file(file, key + ": rotation block is not a rotation");
  }
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(rotation, Eigen::ComputeFullU | Eigen::ComputeFullV);
  transform.linear() = svd.matrixU() * svd.matrixV().transpose();
  transform.translation() = matrix.topRightCorner<3, 1>();
  return transform;
}

/// Intrinsics and T_BS (pose of the camera in the body frame) of one EuRoC camera.
CameraIntrinsics read_euroc_camera(const fs::path& file, Eigen::Isometry3d& T_body_camera) {
  const YAML::Node root = load_sensor_yaml(file);
  if (root["camera_model"] && root["camera_model"].as<std::string>("") != "pinhole") {
    fail_in_file(file, "camera_model: only 'pinhole' is supported, got '" +
                           root["camera_model"].as<std::string>("") + "'");
  }
  const YAML::Node model = root["distortion_model"];
  if (!model) fail_in_file(file, "missing key 'distortion_model'");
  const std::string model_name = model.as<std::string>("");
  if (model_name != "radial-tangential" && model_name != "radtan") {
    fail_in_file(
        file, "distortion_model: only 'radial-tangential' is supported, got '" + model_name + "'");
  }
  CameraIntrinsics camera;
  const std::vector<double> intrinsics = yaml_numbers(root, "intrinsics", 4, file);
  camera.fx = intrinsics[0];
  camera.fy = intrinsics[1];
  camera.cx = intrinsics[2];
  camera.cy = intrinsics[3];
  const std::vector<double> distortion = yaml_numbers(root, "distortion_coefficients", 4, file);
  camera.distortion = Eigen::Vector4d(distortion[0], distortion[1], distortion[2], distortion[3]);
  const std::vector<double> resolution = yaml_numbers(root, "resolution", 2, file);
  camera.width = static_cast<int>(resolution[0]);
  camera.height = static_cast<int>(resolution[1]);
  if (camera.width != resolution[0] || camera.height != resolution[1] || camera.width < 16 ||
      camera.height < 16) {
    fail_in_file(file, "resolution: expected two integers >= 16 (width, height)");
  }
  T_body_camera = yaml_transform(root, "T_BS", file);
  return camera;
}

struct TimedFile {
  std::int64_t timestamp_ns = 0;
  fs::path file;
};

/// cam<i>/data.csv: "#timestamp [ns],filename" rows, each image checked to exist.
std::vector<TimedFile> read_euroc_image_list(const fs::path& camera_folder) {
  const fs::path list = camera_folder / "data.csv";
  text::LineReader reader(list);
  std::vector<TimedFile> images;
  std::string_view line;
  while (reader.next_line(line)) {
    if (text::trimmed(line).starts_with('#')) continue;
    const auto fields = text::split(line, ',');
    if (fields.size() != 2) reader.fail("expected 'timestamp,filename'");
    TimedFile image{reader.integer(fields[0], "timestamp"),
                    camera_folder / "data" / std::string(fields[1])};
    if (!images.empty() && image.timestamp_ns <= images.back().timestamp_ns) {
      reader.fail("time stamps must increase");
    }
    if (!fs::is_regular_file(image.file)) reader.fail("image not found: " + image.file.string());
    images.push_back(std::move(image));
  }
  if (images.empty()) fail_in_file(list, "no images listed");
  return images;
}

/// Ground truth T_world_body at each time stamp, interpolated between the samples that bracket
/// it (linear in position, spherical in rotation).
std::vector<Eigen::Isometry3d> read_euroc_groundtruth(const fs::path& file,
                                                      const std::vector<std::int64_t>& times,
                                                      std::int64_t tolerance_ns) {
  text::LineReader reader(file);
  std::vector<std::int64_t> sample_times;
  std::vector<Eigen::Vector3d> positions;
  std::vector<Eigen::Quaterniond> rotations;
  std::string_view line;
  while (reader.next_line(line)) {
    if (text::trimmed(line).starts_with('#')) continue;
    const auto fields = text::split(line, ',');
    if (fields.size() < 8) {
      reader.fail("expected at least 8 fields (timestamp, p_x, p_y, p_z, q_w, q_x, q_y, q_z)");
    }
    const std::int64_t time = reader.integer(fields[0], "timestamp");
    if (!sample_times.empty() && time <= sample_times.back())
      reader.fail("time stamps must increase");
    sample_times.push_back(time);
    positions.emplace_back(reader.number(fields[1], "p_x"), reader.number(fields[2], "p_y"),
                           reader.number(fields[3], "p_z"));
    Eigen::Quaterniond q(reader.number(fields[4], "q_w"), reader.number(fields[5], "q_x"),
                         reader.number(fields[6], "q_y"), reader.number(fields[7], "q_z"));
    if (std::abs(q.norm() - 1.0) > 1e-2) reader.fail("quaternion is not of unit length");
    rotations.push_back(q.normalized());
  }
  if (sample_times.empty()) fail_in_file(file, "no samples");
  constexpr std::int64_t kLargestGapNs = 50'000'000;
  std::vector<Eigen::Isometry3d> poses;
  for (const std::int64_t time : times) {
    auto after = std::lower_bound(sample_times.begin(), sample_times.end(), time);
    std::size_t upper = static_cast<std::size_t>(after - sample_times.begin());
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    if (upper < sample_times.size() && sample_times[upper] - time <= tolerance_ns) {
      pose.linear() = rotations[upper].toRotationMatrix();
      pose.translation() = positions[upper];
    } else if (upper > 0 && time - sample_times[upper - 1] <= tolerance_ns) {
      pose.linear() = rotations[upper - 1].toRotationMatrix();
      pose.translation() = positions[upper - 1];
    } else if (upper > 0 && upper < sample_times.size() &&
               sample_times[upper] - sample_times[upper - 1] <= kLargestGapNs) {
      const double t = static_cast<double>(time - sample_times[upper - 1]) /
                       static_cast<double>(sample_times[upper] - sample_times[upper - 1]);
      pose.linear() = rotations[upper - 1].slerp(t, rotations[upper]).toRotationMatrix();
      pose.translation() = (1.0 - t) * positions[upper - 1] + t * positions[upper];
    } else {
      fail_in_file(file, "no ground truth at the image time " + std::to_string(time) +
                             " ns (samples cover " + std::to_string(sample_times.front()) + " to " +
                             std::to_string(sample_times.back()) +
                             " ns, with gaps of at most 50 ms); cut the sequence or remove the "
                             "ground-truth file");
    }
    poses.push_back(pose);
  }
  return poses;
}

// ------------------------------------------------------------------------------------------------
// KITTI

/// P0 and P1 of calib.txt as 3x4 matrices.
std::map<std::string, Eigen::Matrix<double, 3, 4>> read_kitti_projections(const fs::path& file) {
  text::LineReader reader(file);
  std::map<std::string, Eigen::Matrix<double, 3, 4>> projections;
  std::string_view line;
  while (reader.next_line(line)) {
    const auto colon = line.find(':');
    if (colon == std::string_view::npos) reader.fail("expected '<name>: <numbers>'");
    const std::string name(text::trimmed(line.substr(0, colon)));
    if (name != "P0" && name != "P1") continue;  // P2, P3 (colour cameras), Tr: not used
    const auto fields = text::split(line.substr(colon + 1), ' ');
    if (fields.size() != 12) {
      reader.fail(name + ": expected 12 numbers (a 3x4 projection matrix, row-major), found " +
                  std::to_string(fields.size()));
    }
    Eigen::Matrix<double, 3, 4> projection;
    for (int index = 0; index < 12; ++index) {
      projection(index / 4, index % 4) = reader.number(fields[index], name + " entry");
    }
    projections[name] = projection;
  }
  return projections;
}

std::vector<double> read_kitti_times(const fs::path& file) {
  text::LineReader reader(file);
  std::vector<double> times;
  std::string_view line;
  while (reader.next_line(line)) {
    const auto fields = text::split(line, ' ');
    if (fields.size() != 1) reader.fail("expected one time in seconds");
    times.push_back(reader.number(fields[0], "time"));
    if (times.size() > 1 && times.back() <= times[times.size() - 2]) {
      reader.fail("times must increase");
    }
  }
  if (times.empty()) fail_in_file(file, "no times");
  return times;
}

std::string kitti_image_name(int frame) {
  char name[32];
  std::snprintf(name, sizeof name, "%06d.png", frame);
  return name;
}

int count_png_files(const fs::path& folder) {
  int count = 0;
  for (const auto& entry : fs::directory_iterator(folder)) {
    if (entry.is_regular_file() && entry.path().extension() == ".png") ++count;
  }
  return count;
}

void cut_to_frames(StereoSequence& sequence, const SequenceReadOptions& options) {
  if (!options.max_frames) return;
  if (*options.max_frames < 1) throw FrontendError("max_frames must be >= 1");
  const auto frames = static_cast<std::size_t>(*options.max_frames);
  if (frames >= sequence.timestamps.size()) return;
  sequence.timestamps.resize(frames);
  sequence.left_images.resize(frames);
  sequence.right_images.resize(frames);
  if (sequence.groundtruth) sequence.groundtruth->resize(frames);
}

fs::path euroc_mav0(const fs::path& folder) {
  if (fs::is_directory(folder / "mav0")) return folder / "mav0";
  return folder;
}

}  // namespace

Eigen::Matrix3d CameraIntrinsics::K() const {
  Eigen::Matrix3d K;
  K << fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0;
  return K;
}

std::vector<std::string> StereoRig::problems() const {
  std::vector<std::string> problems;
  const auto check_camera = [&](const CameraIntrinsics& camera, const std::string& name) {
    if (!(camera.fx > 0.0 && camera.fy > 0.0 && std::isfinite(camera.fx) &&
          std::isfinite(camera.fy))) {
      problems.push_back(name + " focal lengths must be positive and finite (fx " +
                         to_text(camera.fx) + ", fy " + to_text(camera.fy) + ").");
    }
    if (!(camera.cx > 0.0 && camera.cx < camera.width && camera.cy > 0.0 &&
          camera.cy < camera.height)) {
      problems.push_back(name + " principal point (" + to_text(camera.cx) + ", " +
                         to_text(camera.cy) + ") must be inside the " +
                         std::to_string(camera.width) + "x" + std::to_string(camera.height) +
                         " image.");
    }
    if (!camera.distortion.allFinite()) {
      problems.push_back(name + " distortion coefficients must be finite.");
    }
  };
  check_camera(left, "left camera");
  check_camera(right, "right camera");
  if (left.width != right.width || left.height != right.height) {
    problems.push_back("left and right image sizes differ.");
  }
  if (!finite(T_cam0_cam1) || !finite(T_cam0_body)) {
    problems.push_back("extrinsics must be finite.");
    return problems;
  }
  const Eigen::Vector3d baseline = T_cam0_cam1.translation();
  if (baseline.norm() < 1e-3) {
    problems.push_back("the stereo baseline is " + to_text(baseline.norm()) +
                       " m; it must be at least 1 mm.");
  } else if (std::abs(baseline.x()) < 0.7 * baseline.norm()) {
    problems.push_back(
        "the right camera must be beside the left one (baseline mostly along the "
        "left camera's x axis); the baseline is (" +
        to_text(baseline.x()) + ", " + to_text(baseline.y()) + ", " + to_text(baseline.z()) +
        ") m.");
  }
  const Eigen::AngleAxisd relative_rotation(T_cam0_cam1.rotation());
  if (std::abs(relative_rotation.angle()) > 0.35) {
    problems.push_back("the cameras' optical axes differ by " +
                       to_text(relative_rotation.angle() * 180.0 / 3.14159265358979) +
                       " degrees; at most 20 are supported.");
  }
  return problems;
}

StereoSequence read_euroc_sequence(const fs::path& folder, const SequenceReadOptions& options) {
  const fs::path mav0 = euroc_mav0(folder);
  if (!fs::is_directory(mav0 / "cam0") || !fs::is_directory(mav0 / "cam1")) {
    fail_in_file(mav0, "not an EuRoC sequence (expected the folders cam0/ and cam1/)");
  }
  StereoSequence sequence;
  sequence.layout = SequenceLayout::kEuroc;
  sequence.root = folder;
  Eigen::Isometry3d T_body_cam0, T_body_cam1;
  sequence.rig.left = read_euroc_camera(mav0 / "cam0" / "sensor.yaml", T_body_cam0);
  sequence.rig.right = read_euroc_camera(mav0 / "cam1" / "sensor.yaml", T_body_cam1);
  sequence.rig.T_cam0_body = T_body_cam0.inverse();
  sequence.rig.T_cam0_cam1 = T_body_cam0.inverse() * T_body_cam1;
  check_rig(sequence.rig, mav0 / "cam1" / "sensor.yaml");

  const std::vector<TimedFile> left = read_euroc_image_list(mav0 / "cam0");
  const std::vector<TimedFile> right = read_euroc_image_list(mav0 / "cam1");
  if (left.size() != right.size()) {
    fail_in_file(mav0 / "cam1" / "data.csv",
                 "lists " + std::to_string(right.size()) + " images but cam0/data.csv lists " +
                     std::to_string(left.size()) + "; every left image needs its right image");
  }
  std::vector<std::int64_t> times;
  for (std::size_t frame = 0; frame < left.size(); ++frame) {
    const std::int64_t difference = std::abs(left[frame].timestamp_ns - right[frame].timestamp_ns);
    if (difference > options.max_time_difference_ns) {
      fail_in_file(mav0 / "cam1" / "data.csv",
                   "image " + std::to_string(frame + 1) + " has time stamp " +
                       std::to_string(right[frame].timestamp_ns) + " ns, but the left image's is " +
                       std::to_string(left[frame].timestamp_ns) + " ns (mismatched by " +
                       std::to_string(difference) + " ns, at most " +
                       std::to_string(options.max_time_difference_ns) + " ns allowed)");
    }
    times.push_back(left[frame].timestamp_ns);
    sequence.timestamps.push_back(1e-9 * static_cast<double>(left[frame].timestamp_ns));
    sequence.left_images.push_back(left[frame].file);
    sequence.right_images.push_back(right[frame].file);
  }
  if (options.max_frames && *options.max_frames >= 1 &&
      times.size() > static_cast<std::size_t>(*options.max_frames)) {
    times.resize(*options.max_frames);
  }
  const fs::path groundtruth = mav0 / "state_groundtruth_estimate0" / "data.csv";
  if (fs::exists(groundtruth)) {
    sequence.groundtruth =
        read_euroc_groundtruth(groundtruth, times, options.max_time_difference_ns);
  }
  cut_to_frames(sequence, options);
  return sequence;
}

StereoSequence read_kitti_sequence(const fs::path& folder, const SequenceReadOptions& options) {
  const fs::path calibration_file = folder / "calib.txt";
  auto projections = read_kitti_projections(calibration_file);
  for (const char* name : {"P0", "P1"}) {
    if (!projections.count(name)) fail_in_file(calibration_file, std::string("missing ") + name);
  }
  const Eigen::Matrix<double, 3, 4>& P0 = projections["P0"];
  const Eigen::Matrix<double, 3, 4>& P1 = projections["P1"];
  if (!P0.col(3).isZero(1e-9)) {
    fail_in_file(calibration_file, "P0: the last column must be zero (P0 = K [I | 0])");
  }
  if (!P0.leftCols<3>().isApprox(P1.leftCols<3>(), 1e-9)) {
    fail_in_file(calibration_file,
                 "P0 and P1 must share K (rectified images: P1 = K [I | -baseline, 0, 0])");
  }
  if (!(P1(1, 3) == 0.0 && P1(2, 3) == 0.0)) {
    fail_in_file(calibration_file, "P1: the right camera must be displaced along x only");
  }
  if (!(P0(1, 0) == 0.0 && P0(2, 0) == 0.0 && P0(2, 1) == 0.0 && P0(2, 2) == 1.0)) {
    fail_in_file(calibration_file, "P0: K must be upper triangular with K(2, 2) = 1");
  }

  const fs::path left_folder = folder / "image_0";
  const fs::path right_folder = folder / "image_1";
  for (const fs::path& images : {left_folder, right_folder}) {
    if (!fs::is_directory(images)) fail_in_file(images, "image folder not found");
  }
  StereoSequence sequence;
  sequence.layout = SequenceLayout::kKitti;
  sequence.root = folder;
  sequence.timestamps = read_kitti_times(folder / "times.txt");
  const int frames = sequence.num_frames();
  const int left_count = count_png_files(left_folder);
  if (left_count != frames) {
    fail_in_file(folder / "times.txt", "has " + std::to_string(frames) + " times but " +
                                           left_folder.string() + " holds " +
                                           std::to_string(left_count) + " images");
  }
  for (int frame = 0; frame < frames; ++frame) {
    sequence.left_images.push_back(left_folder / kitti_image_name(frame));
    sequence.right_images.push_back(right_folder / kitti_image_name(frame));
    for (const fs::path* image : {&sequence.left_images.back(), &sequence.right_images.back()}) {
      if (!fs::is_regular_file(*image)) {
        fail_in_file(*image, "image not found (frame " + std::to_string(frame) + " of " +
                                 std::to_string(frames) + " listed in times.txt)");
      }
    }
  }

  const cv::Mat first = cv::imread(sequence.left_images.front().string(), cv::IMREAD_UNCHANGED);
  if (first.empty()) fail_in_file(sequence.left_images.front(), "cannot decode the image");
  CameraIntrinsics camera;
  camera.fx = P0(0, 0);
  camera.fy = P0(1, 1);
  camera.cx = P0(0, 2);
  camera.cy = P0(1, 2);
  camera.width = first.cols;
  camera.height = first.rows;
  sequence.rig.left = camera;
  sequence.rig.right = camera;
  sequence.rig.rectified = true;
  sequence.rig.T_cam0_cam1.translation() = Eigen::Vector3d(-P1(0, 3) / P1(0, 0), 0.0, 0.0);
  check_rig(sequence.rig, calibration_file);

  const fs::path poses = folder / "poses.txt";
  if (fs::exists(poses)) {
    try {
      sequence.groundtruth = dataset::read_trajectory_kitti(poses);
    } catch (const std::runtime_error& error) {
      throw FrontendError(error.what());
    }
    if (static_cast<int>(sequence.groundtruth->size()) != frames) {
      fail_in_file(poses, "has " + std::to_string(sequence.groundtruth->size()) +
                              " poses but times.txt has " + std::to_string(frames) + " times");
    }
  }
  cut_to_frames(sequence, options);
  return sequence;
}

bool is_stereo_sequence(const fs::path& folder) {
  return fs::is_regular_file(folder / "calib.txt") || fs::is_directory(euroc_mav0(folder) / "cam0");
}

StereoSequence read_stereo_sequence(const fs::path& folder, const SequenceReadOptions& options) {
  if (!fs::is_directory(folder)) fail_in_file(folder, "sequence folder not found");
  if (fs::is_regular_file(folder / "calib.txt")) return read_kitti_sequence(folder, options);
  if (fs::is_directory(euroc_mav0(folder) / "cam0")) return read_euroc_sequence(folder, options);
  fail_in_file(folder,
               "not a stereo sequence: expected calib.txt, image_0/ and image_1/ (KITTI) or "
               "mav0/cam0/ and mav0/cam1/ (EuRoC)");
}

std::string format_kitti_calibration(const Eigen::Matrix3d& K, double baseline) {
  std::string out;
  for (int camera = 0; camera < 2; ++camera) {
    Eigen::Matrix<double, 3, 4> P = Eigen::Matrix<double, 3, 4>::Zero();
    P.leftCols<3>() = K;
    if (camera == 1) P(0, 3) = -K(0, 0) * baseline;
    out += "P" + std::to_string(camera) + ":";
    for (int index = 0; index < 12; ++index) out += " " + to_text(P(index / 4, index % 4));
    out += "\n";
  }
  return out;
}

}  // namespace concord::frontend
