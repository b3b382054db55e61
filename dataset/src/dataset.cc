#include "concord/dataset/dataset.h"

#include <Eigen/Cholesky>

#include <algorithm>
#include <array>
#include <charconv>
#include <limits>
#include <nlohmann/json.hpp>
#include <span>
#include <stdexcept>
#include <string_view>
#include <utility>

#include "concord/dataset/result_io.h"
#include "text_parsing.h"

namespace concord::dataset {

namespace {

using text_parsing::append_integer;
using text_parsing::append_number;
using text_parsing::CsvReader;
using text_parsing::fail_in_file;

constexpr std::string_view kDescriptionFile = "dataset.json";
constexpr std::string_view kObjectsGroundtruthFile = "objects_gt.csv";
constexpr std::string_view kGroundtruthFile = "groundtruth.kitti";
constexpr std::string_view kOdometryFile = "odometry.kitti";
constexpr std::string_view kObjectsFile = "objects.csv";
constexpr std::string_view kFeaturesFile = "features.csv";
constexpr std::string_view kOdometryCovarianceFile = "odometry_covariance.csv";
constexpr std::string_view kObjectTruthIdsFile = "object_ids_truth.csv";
constexpr std::string_view kRobotFolderPrefix = "robot_";

constexpr std::array<std::string_view, 4> kObjectsGroundtruthColumns{"id", "x", "y", "z"};
constexpr std::array<std::string_view, 6> kObservationColumns{"frame",  "id",      "u_left",
                                                              "v_left", "u_right", "v_right"};
/// objects.csv may carry the detector's class after the observation columns.
constexpr std::array<std::string_view, 1> kObjectClassColumn{"class"};
/// features.csv may carry each observation's own noise (StereoObservation::sigma) after them.
constexpr std::array<std::string_view, 2> kFeatureSigmaColumns{"sigma_left", "sigma_right"};
constexpr std::array<std::string_view, 2> kObjectTruthIdsColumns{"id", "truth_id"};

/// The NN of a robot_NN folder name (two or more digits); nullopt if the name does not start
/// with "robot_"; DatasetError if it does but is not of that form.
std::optional<int> robot_folder_index(const std::filesystem::path& folder) {
  const std::string name = folder.filename().string();
  if (!name.starts_with(kRobotFolderPrefix)) return std::nullopt;
  const std::string_view digits = std::string_view(name).substr(kRobotFolderPrefix.size());
  const bool all_digits =
      std::all_of(digits.begin(), digits.end(), [](char c) { return c >= '0' && c <= '9'; });
  int index = -1;
  if (digits.size() < 2 || !all_digits ||
      std::from_chars(digits.data(), digits.data() + digits.size(), index).ec != std::errc()) {
    fail_in_file(folder, "robot folders must be named robot_NN (two or more digits)");
  }
  return index;
}

/// Indices of the robot_NN folders of `directory`, sorted.
std::vector<int> list_robot_folders(const std::filesystem::path& directory) {
  std::vector<int> indices;
  for (const auto& entry : std::filesystem::directory_iterator(directory)) {
    if (!entry.is_directory()) continue;
    if (const auto index = robot_folder_index(entry.path())) indices.push_back(*index);
  }
  std::sort(indices.begin(), indices.end());
  return indices;
}

/// The contents of dataset.json that the reader uses.
struct Description {
  std::optional<std::string> name;
  std::string sensor;
  std::optional<int> robots;
  StereoCamera camera;
  ObjectIds object_ids = ObjectIds::kGlobal;
  StartPoses start_poses = StartPoses::kKnown;
};

/// A rows x columns matrix stored as a JSON array of rows at camera.<key>.
Eigen::MatrixXd read_json_matrix(const nlohmann::json& camera, const std::string& key, int rows,
                                 int columns, const std::filesystem::path& file) {
  const std::string problem = "camera." + key + " must be a " + std::to_string(rows) + "x" +
                              std::to_string(columns) + " array of numbers (an array of rows)";
  if (!camera.contains(key)) fail_in_file(file, "missing camera." + key);
  const nlohmann::json& value = camera.at(key);
  if (!value.is_array() || value.size() != static_cast<std::size_t>(rows)) {
    fail_in_file(file, problem);
  }
  Eigen::MatrixXd matrix(rows, columns);
  for (int row = 0; row < rows; ++row) {
    const nlohmann::json& row_value = value.at(row);
    if (!row_value.is_array() || row_value.size() != static_cast<std::size_t>(columns)) {
      fail_in_file(file, problem);
    }
    for (int column = 0; column < columns; ++column) {
      if (!row_value.at(column).is_number()) fail_in_file(file, problem);
      matrix(row, column) = row_value.at(column).get<double>();
    }
  }
  return matrix;
}

/// A 4x4 rigid transform at camera.<key>: last row [0 0 0 1], rotation block a rotation.
Eigen::Isometry3d read_json_transform(const nlohmann::json& camera, const std::string& key,
                                      const std::filesystem::path& file) {
  const Eigen::Matrix4d matrix = read_json_matrix(camera, key, 4, 4, file);
  if (!matrix.row(3).isApprox(Eigen::RowVector4d(0.0, 0.0, 0.0, 1.0), 1e-9)) {
    fail_in_file(file, "camera." + key + ": last row must be [0, 0, 0, 1]");
  }
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();
  transform.matrix().topRows<3>() = matrix.topRows<3>();
  const std::string problem = text_parsing::check_and_orthonormalize_rotation(transform);
  if (!problem.empty()) fail_in_file(file, "camera." + key + ": " + problem);
  return transform;
}

/// The whole of a JSON file, which must hold an object.
nlohmann::json read_json_object(const std::filesystem::path& file) {
  const std::string text = text_parsing::read_whole_file(file);
  nlohmann::json root;
  try {
    root = nlohmann::json::parse(text);
  } catch (const nlohmann::json::parse_error& error) {
    fail_in_file(file, std::string("invalid JSON: ") + error.what());
  }
  if (!root.is_object()) fail_in_file(file, "expected a JSON object");
  return root;
}

/// dataset.json's "object_ids" and "start_poses".
Conventions parse_conventions(const nlohmann::json& root, const std::filesystem::path& file) {
  Conventions conventions;
  if (root.contains("object_ids")) {
    const nlohmann::json& value = root["object_ids"];
    if (!value.is_string() || (value != "global" && value != "private")) {
      fail_in_file(file, "\"object_ids\" must be \"global\" or \"private\", got " + value.dump());
    }
    conventions.object_ids = value == "private" ? ObjectIds::kPrivate : ObjectIds::kGlobal;
  }
  if (root.contains("start_poses")) {
    const nlohmann::json& value = root["start_poses"];
    if (!value.is_string() || (value != "known" && value != "unknown")) {
      fail_in_file(file, "\"start_poses\" must be \"known\" or \"unknown\", got " + value.dump());
    }
    conventions.start_poses = value == "unknown" ? StartPoses::kUnknown : StartPoses::kKnown;
  }
  return conventions;
}

Description read_description(const std::filesystem::path& file) {
  nlohmann::json root = read_json_object(file);
  Description description;
  if (root.contains("name")) {
    if (!root["name"].is_string()) fail_in_file(file, "\"name\" must be a string");
    description.name = root["name"].get<std::string>();
  }
  if (root.contains("sensor")) {
    if (!root["sensor"].is_string()) fail_in_file(file, "\"sensor\" must be a string");
    description.sensor = root["sensor"].get<std::string>();
  }
  if (root.contains("robots")) {
    if (!root["robots"].is_number_integer() || root["robots"].get<int>() < 1) {
      fail_in_file(file, "\"robots\" must be a positive integer");
    }
    description.robots = root["robots"].get<int>();
  }
  const Conventions conventions = parse_conventions(root, file);
  description.object_ids = conventions.object_ids;
  description.start_poses = conventions.start_poses;
  if (!root.contains("camera") || !root["camera"].is_object()) {
    fail_in_file(file, "missing \"camera\" object");
  }
  const nlohmann::json& camera = root["camera"];
  const Eigen::Matrix3d intrinsics = read_json_matrix(camera, "K", 3, 3, file);
  if (!(intrinsics(0, 0) > 0.0 && intrinsics(1, 1) > 0.0) ||
      !intrinsics.row(2).isApprox(Eigen::RowVector3d(0.0, 0.0, 1.0), 1e-12)) {
    fail_in_file(file, "camera.K must have positive focal lengths and last row [0, 0, 1]");
  }
  description.camera.K = intrinsics;
  description.camera.T_cam0_body = read_json_transform(camera, "T_cam_body", file);
  description.camera.T_cam0_cam1 = read_json_transform(camera, "T_cam0_cam1", file);
  return description;
}

std::map<LandmarkId, Eigen::Vector3d> read_objects_groundtruth(const std::filesystem::path& file) {
  std::map<LandmarkId, Eigen::Vector3d> objects;
  CsvReader table(file, kObjectsGroundtruthColumns);
  while (table.next_row()) {
    const LandmarkId id = table.integer(0);
    const Eigen::Vector3d position(table.number(1), table.number(2), table.number(3));
    if (!objects.emplace(id, position).second) {
      table.fail("duplicate id " + std::to_string(id));
    }
  }
  return objects;
}

/// Observations per frame, for frames 0..num_frames-1; with `classes`, the optional class column
/// is accepted and its values go to *classes (parallel to the observations; all empty without the
/// column).
std::vector<std::vector<StereoObservation>> read_observations(
    const std::filesystem::path& file, int num_frames,
    std::vector<std::vector<int>>* classes = nullptr, bool* has_classes = nullptr) {
  std::vector<std::vector<StereoObservation>> per_frame(num_frames);
  // objects.csv: an optional class; features.csv: an optional noise per observation.
  CsvReader table(file, kObservationColumns,
                  classes != nullptr ? std::span<const std::string_view>(kObjectClassColumn)
                                     : std::span<const std::string_view>(kFeatureSigmaColumns));
  if (classes != nullptr) classes->assign(num_frames, {});
  if (has_classes != nullptr) *has_classes = table.has_optional_columns();
  while (table.next_row()) {
    const std::int64_t frame = table.integer(0);
    if (frame < 0 || frame >= num_frames) {
      table.fail("frame " + std::to_string(frame) + " is outside [0, " +
                 std::to_string(num_frames - 1) + "] (the robot has " + std::to_string(num_frames) +
                 " ground-truth poses)");
    }
    StereoObservation observation;
    observation.id = table.integer(1);
    observation.uv =
        Eigen::Vector4d(table.number(2), table.number(3), table.number(4), table.number(5));
    if (classes == nullptr && table.has_optional_columns()) {
      observation.sigma = Eigen::Vector2d(table.number(6), table.number(7));
      if (!valid_observation_sigma(observation.sigma)) {
        table.fail(
            "sigma_left and sigma_right must both be > 0 (the observation's own noise, pixels, "
            "from 1e-6 to 1e6) or both 0 (the configured feature_noise)");
      }
    }
    per_frame[frame].push_back(observation);
    if (classes != nullptr && table.has_optional_columns()) {
      const std::int64_t object_class = table.integer(6);
      if (object_class < 0 || object_class > std::numeric_limits<int>::max()) {
        table.fail("class " + std::to_string(object_class) + " must be an integer >= 0");
      }
      (*classes)[frame].push_back(static_cast<int>(object_class));
    }
  }
  return per_frame;
}

/// odometry_covariance.csv: one row per odometry entry at most, frame in [1, num_frames), each
/// covariance finite, symmetric positive definite.
std::vector<std::optional<Eigen::Matrix<double, 6, 6>>> read_odometry_covariance(
    const std::filesystem::path& file, int num_frames) {
  std::vector<std::optional<Eigen::Matrix<double, 6, 6>>> covariances(
      static_cast<std::size_t>(std::max(num_frames - 1, 0)));
  for (const PoseCovariance& entry : read_pose_covariances_csv(file)) {
    if (entry.frame < 1 || entry.frame >= num_frames) {
      fail_in_file(file, "frame " + std::to_string(entry.frame) + " outside [1, " +
                             std::to_string(num_frames) + "): row k is the motion k-1 -> k");
    }
    auto& slot = covariances[static_cast<std::size_t>(entry.frame - 1)];
    if (slot) fail_in_file(file, "frame " + std::to_string(entry.frame) + " given twice");
    const Eigen::LLT<Eigen::Matrix<double, 6, 6>> llt(entry.covariance);
    if (!entry.covariance.allFinite() || llt.info() != Eigen::Success) {
      fail_in_file(file, "frame " + std::to_string(entry.frame) +
                             ": covariance is not finite and positive definite");
    }
    slot = entry.covariance;
  }
  return covariances;
}

std::string format_odometry_covariance(
    const std::vector<std::optional<Eigen::Matrix<double, 6, 6>>>& covariances) {
  std::vector<PoseCovariance> entries;
  for (std::size_t index = 0; index < covariances.size(); ++index) {
    if (covariances[index]) entries.push_back({static_cast<int>(index + 1), *covariances[index]});
  }
  return format_pose_covariances_csv(entries);
}

std::map<LandmarkId, LandmarkId> read_object_truth_ids(const std::filesystem::path& file) {
  std::map<LandmarkId, LandmarkId> truth_ids;
  CsvReader table(file, kObjectTruthIdsColumns);
  while (table.next_row()) {
    const LandmarkId id = table.integer(0);
    const LandmarkId truth_id = table.integer(1);
    if (truth_id < kNoTruthId) {
      table.fail("truth_id " + std::to_string(truth_id) + " must be >= -1 (-1: false detection)");
    }
    if (!truth_ids.emplace(id, truth_id).second) table.fail("duplicate id " + std::to_string(id));
  }
  return truth_ids;
}

/// Keeps the first `frames` frames (all if there are fewer).
void cut_to_frames(RobotData& robot, int frames) {
  if (frames >= robot.num_frames()) return;
  robot.groundtruth.resize(frames);
  robot.odometry.resize(std::max(frames - 1, 0));
  robot.objects.resize(frames);
  robot.features.resize(frames);
  if (!robot.odometry_covariance.empty()) robot.odometry_covariance.resize(std::max(frames - 1, 0));
  if (robot.has_object_classes) robot.object_classes.resize(frames);
}

RobotData read_robot(const std::filesystem::path& folder, int index, const ReadOptions& options) {
  RobotData robot;
  robot.index = index;
  const std::filesystem::path groundtruth_file = folder / kGroundtruthFile;
  const std::filesystem::path odometry_file = folder / kOdometryFile;
  robot.groundtruth = text_parsing::read_kitti_poses(groundtruth_file);
  if (robot.groundtruth.empty()) fail_in_file(groundtruth_file, "no poses");
  robot.odometry = text_parsing::read_kitti_poses(odometry_file);
  const int num_frames = robot.num_frames();
  if (robot.odometry.size() + 1 != robot.groundtruth.size()) {
    fail_in_file(odometry_file, std::to_string(robot.odometry.size()) + " poses, expected " +
                                    std::to_string(num_frames - 1) + " (one fewer than the " +
                                    std::to_string(num_frames) + " poses of " +
                                    groundtruth_file.string() + ")");
  }
  robot.objects = read_observations(folder / kObjectsFile, num_frames, &robot.object_classes,
                                    &robot.has_object_classes);
  if (!robot.has_object_classes) robot.object_classes.assign(num_frames, {});
  const std::filesystem::path truth_ids_file = folder / kObjectTruthIdsFile;
  robot.has_object_truth_ids = std::filesystem::exists(truth_ids_file);
  if (robot.has_object_truth_ids) robot.object_truth_ids = read_object_truth_ids(truth_ids_file);
  const std::filesystem::path features_file = folder / kFeaturesFile;
  robot.has_features = options.load_features && std::filesystem::exists(features_file);
  if (robot.has_features) {
    robot.features = read_observations(features_file, num_frames);
  } else {
    robot.features.assign(num_frames, {});
  }
  const std::filesystem::path covariance_file = folder / kOdometryCovarianceFile;
  if (options.load_odometry_covariance && std::filesystem::exists(covariance_file)) {
    robot.odometry_covariance = read_odometry_covariance(covariance_file, num_frames);
  }
  if (options.max_frames) cut_to_frames(robot, *options.max_frames);
  return robot;
}

/// Writes observations, with the classes' column when given, else with the noise columns when
/// any observation has its own noise.
std::string format_observations(const std::vector<std::vector<StereoObservation>>& per_frame,
                                const std::vector<std::vector<int>>* classes = nullptr) {
  std::string out = text_parsing::csv_header(kObservationColumns);
  const bool sigmas =
      classes == nullptr && std::any_of(per_frame.begin(), per_frame.end(), [](const auto& frame) {
        return std::any_of(frame.begin(), frame.end(), [](const StereoObservation& observation) {
          return !observation.sigma.isZero(0.0);
        });
      });
  if (classes != nullptr) out += "," + std::string(kObjectClassColumn[0]);
  if (sigmas) {
    for (const std::string_view column : kFeatureSigmaColumns) out += "," + std::string(column);
  }
  out += '\n';
  for (std::size_t frame = 0; frame < per_frame.size(); ++frame) {
    for (std::size_t n = 0; n < per_frame[frame].size(); ++n) {
      const StereoObservation& observation = per_frame[frame][n];
      append_integer(out, static_cast<std::int64_t>(frame));
      out += ',';
      append_integer(out, observation.id);
      for (int coordinate = 0; coordinate < 4; ++coordinate) {
        out += ',';
        append_number(out, observation.uv[coordinate]);
      }
      if (classes != nullptr) {
        out += ',';
        append_integer(out, (*classes)[frame][n]);
      }
      for (int side = 0; sigmas && side < 2; ++side) {
        out += ',';
        append_number(out, observation.sigma[side]);
      }
      out += '\n';
    }
  }
  return out;
}

std::string format_object_truth_ids(const std::map<LandmarkId, LandmarkId>& truth_ids) {
  std::string out = text_parsing::csv_header(kObjectTruthIdsColumns) + '\n';
  for (const auto& [id, truth_id] : truth_ids) {
    append_integer(out, id);
    out += ',';
    append_integer(out, truth_id);
    out += '\n';
  }
  return out;
}

std::string format_objects_groundtruth(const std::map<LandmarkId, Eigen::Vector3d>& objects) {
  std::string out = text_parsing::csv_header(kObjectsGroundtruthColumns) + '\n';
  for (const auto& [id, position] : objects) {
    append_integer(out, id);
    for (int axis = 0; axis < 3; ++axis) {
      out += ',';
      append_number(out, position[axis]);
    }
    out += '\n';
  }
  return out;
}

nlohmann::ordered_json matrix_to_json(const Eigen::MatrixXd& matrix) {
  nlohmann::ordered_json rows = nlohmann::ordered_json::array();
  for (int row = 0; row < matrix.rows(); ++row) {
    nlohmann::ordered_json values = nlohmann::ordered_json::array();
    for (int column = 0; column < matrix.cols(); ++column) values.push_back(matrix(row, column));
    rows.push_back(values);
  }
  return rows;
}

std::string format_description(const Dataset& dataset) {
  const StereoCamera& camera = dataset.camera;
  const bool has_features = std::any_of(dataset.robots.begin(), dataset.robots.end(),
                                        [](const RobotData& robot) { return robot.has_features; });
  nlohmann::ordered_json root;
  root["name"] = dataset.name;
  if (!dataset.sensor.empty()) root["sensor"] = dataset.sensor;
  root["robots"] = dataset.robots.size();
  root["object_ids"] = to_string(dataset.object_ids);
  root["start_poses"] = to_string(dataset.start_poses);
  root["camera"] = {{"K", matrix_to_json(camera.K)},
                    {"T_cam_body", matrix_to_json(camera.T_cam0_body.matrix())},
                    {"T_cam0_cam1", matrix_to_json(camera.T_cam0_cam1.matrix())},
                    {"fx_times_baseline", camera.K(0, 0) * camera.baseline()}};
  root["observations_in"] =
      camera.K.isIdentity(0.0) ? "normalized image coordinates (K is identity)" : "pixels";
  root["has_geometric_features"] = has_features;
  return root.dump(2) + '\n';
}

void check_consistent(const RobotData& robot, std::size_t position) {
  const std::size_t frames = robot.groundtruth.size();
  const auto fail = [&](const std::string& problem) {
    throw std::invalid_argument("write_dataset: robot " + std::to_string(position) + ": " +
                                problem);
  };
  if (frames == 0) fail("no ground-truth poses");
  if (robot.odometry.size() + 1 != frames) fail("odometry must have one entry fewer than poses");
  if (robot.objects.size() != frames) fail("objects must have one entry per frame");
  if (robot.has_features && robot.features.size() != frames) {
    fail("features must have one entry per frame");
  }
  if (robot.has_object_classes) {
    if (robot.object_classes.size() != frames) fail("object_classes must have one entry per frame");
    for (std::size_t k = 0; k < frames; ++k) {
      if (robot.object_classes[k].size() != robot.objects[k].size()) {
        fail("object_classes must have one class per object observation (frame " +
             std::to_string(k) + ")");
      }
    }
  }
}

}  // namespace

int RobotData::num_frames() const { return static_cast<int>(groundtruth.size()); }

namespace {

/// Frame k's inputs of one robot (RobotData and RobotInputs share the layout).
template <typename Robot>
FrameInput robot_frame_input(const Robot& robot, int frame) {
  if (frame < 0 || frame >= robot.num_frames()) {
    throw std::out_of_range("frame " + std::to_string(frame) + " outside [0, " +
                            std::to_string(robot.num_frames()) + ")");
  }
  FrameInput input;
  input.frame = frame;
  if (frame > 0) {
    const auto step = static_cast<std::size_t>(frame - 1);
    input.T_previous_current = robot.odometry.at(step);
    if (step < robot.odometry_covariance.size())
      input.odometry_covariance = robot.odometry_covariance[step];
  }
  input.objects = robot.objects.at(frame);
  if (frame < static_cast<int>(robot.features.size())) input.features = robot.features[frame];
  return input;
}

}  // namespace

FrameInput RobotData::frame_input(int frame) const { return robot_frame_input(*this, frame); }

std::string robot_folder_name(int index) {
  std::string name(kRobotFolderPrefix);
  if (index < 10) name += '0';
  return name + std::to_string(index);
}

StereoCamera read_camera(const std::filesystem::path& dataset_json) {
  return read_description(dataset_json).camera;
}

Conventions read_conventions(const std::filesystem::path& dataset_json) {
  return parse_conventions(read_json_object(dataset_json), dataset_json);
}

Dataset read_dataset(const std::filesystem::path& directory, const ReadOptions& options) {
  if (options.max_frames && *options.max_frames < 1) {
    throw std::invalid_argument("read_dataset: max_frames must be >= 1");
  }
  if (options.max_robots && *options.max_robots < 1) {
    throw std::invalid_argument("read_dataset: max_robots must be >= 1");
  }
  if (options.only_robot && *options.only_robot < 0) {
    throw std::invalid_argument("read_dataset: only_robot must be >= 0");
  }
  if (!std::filesystem::is_directory(directory))
    fail_in_file(directory, "dataset folder not found");

  const std::filesystem::path description_file = directory / kDescriptionFile;
  Description description = read_description(description_file);

  Dataset dataset;
  dataset.root = directory;
  dataset.camera = description.camera;
  dataset.sensor = description.sensor;
  dataset.object_ids = description.object_ids;
  dataset.start_poses = description.start_poses;
  if (description.name) {
    dataset.name = *description.name;
  } else {
    const std::filesystem::path normal = std::filesystem::absolute(directory).lexically_normal();
    dataset.name = (normal.has_filename() ? normal : normal.parent_path()).filename().string();
  }

  const std::filesystem::path objects_groundtruth_file = directory / kObjectsGroundtruthFile;
  if (std::filesystem::exists(objects_groundtruth_file)) {
    dataset.objects_groundtruth = read_objects_groundtruth(objects_groundtruth_file);
  }

  const std::vector<int> indices = list_robot_folders(directory);
  if (indices.empty()) fail_in_file(directory, "no robot_NN folders");
  for (std::size_t position = 0; position < indices.size(); ++position) {
    if (indices[position] != static_cast<int>(position)) {
      fail_in_file(directory / robot_folder_name(static_cast<int>(position)),
                   "robot folder not found (robot folders must be numbered consecutively from "
                   "robot_00)");
    }
  }
  if (description.robots && *description.robots != static_cast<int>(indices.size())) {
    fail_in_file(description_file, "\"robots\" is " + std::to_string(*description.robots) +
                                       " but the folder has " + std::to_string(indices.size()) +
                                       " robot_NN folders");
  }

  const int robot_count = static_cast<int>(indices.size());
  if (options.only_robot) {
    if (*options.only_robot >= robot_count) {
      fail_in_file(directory / robot_folder_name(*options.only_robot),
                   "robot folder not found (the dataset has " + std::to_string(robot_count) +
                       " robots)");
    }
    dataset.robots.push_back(read_robot(directory / robot_folder_name(*options.only_robot),
                                        *options.only_robot, options));
    return dataset;
  }
  const int robots_to_read = std::min(robot_count, options.max_robots.value_or(robot_count));
  for (int index = 0; index < robots_to_read; ++index) {
    dataset.robots.push_back(read_robot(directory / robot_folder_name(index), index, options));
  }
  return dataset;
}

void write_dataset(const Dataset& dataset, const std::filesystem::path& directory) {
  for (std::size_t position = 0; position < dataset.robots.size(); ++position) {
    check_consistent(dataset.robots[position], position);
  }
  std::filesystem::create_directories(directory);
  for (const int index : list_robot_folders(directory)) {
    if (index >= static_cast<int>(dataset.robots.size())) {
      fail_in_file(directory / robot_folder_name(index),
                   "would be read as an extra robot; remove it or write to an empty folder");
    }
  }

  write_file_atomically(directory / kDescriptionFile, format_description(dataset));
  write_file_atomically(directory / kObjectsGroundtruthFile,
                        format_objects_groundtruth(dataset.objects_groundtruth));
  for (std::size_t position = 0; position < dataset.robots.size(); ++position) {
    const RobotData& robot = dataset.robots[position];
    const std::filesystem::path folder = directory / robot_folder_name(static_cast<int>(position));
    std::filesystem::create_directories(folder);
    write_file_atomically(folder / kGroundtruthFile,
                          text_parsing::format_kitti_poses(robot.groundtruth));
    write_file_atomically(folder / kOdometryFile, text_parsing::format_kitti_poses(robot.odometry));
    write_file_atomically(
        folder / kObjectsFile,
        format_observations(robot.objects,
                            robot.has_object_classes ? &robot.object_classes : nullptr));
    if (robot.has_object_truth_ids) {
      write_file_atomically(folder / kObjectTruthIdsFile,
                            format_object_truth_ids(robot.object_truth_ids));
    } else {
      std::filesystem::remove(folder / kObjectTruthIdsFile);
    }
    if (robot.has_features) {
      write_file_atomically(folder / kFeaturesFile, format_observations(robot.features));
    } else {
      std::filesystem::remove(folder / kFeaturesFile);
    }
    if (!robot.odometry_covariance.empty()) {
      write_file_atomically(folder / kOdometryCovarianceFile,
                            format_odometry_covariance(robot.odometry_covariance));
    } else {
      std::filesystem::remove(folder / kOdometryCovarianceFile);
    }
  }
}

Dataset slice(const Dataset& dataset, int frames, int robots) {
  if (frames < 1 || robots < 1) {
    throw std::invalid_argument("slice: frames and robots must be >= 1");
  }
  Dataset cut;
  cut.name = dataset.name;
  cut.sensor = dataset.sensor;
  cut.root = dataset.root;
  cut.camera = dataset.camera;
  cut.objects_groundtruth = dataset.objects_groundtruth;
  cut.object_ids = dataset.object_ids;
  cut.start_poses = dataset.start_poses;
  const std::size_t kept_robots = std::min(dataset.robots.size(), static_cast<std::size_t>(robots));
  cut.robots.assign(dataset.robots.begin(), dataset.robots.begin() + kept_robots);
  for (RobotData& robot : cut.robots) cut_to_frames(robot, frames);
  return cut;
}

std::string to_string(ObjectIds object_ids) {
  return object_ids == ObjectIds::kPrivate ? "private" : "global";
}

std::string to_string(StartPoses start_poses) {
  return start_poses == StartPoses::kUnknown ? "unknown" : "known";
}

FrameInput RobotInputs::frame_input(int frame) const { return robot_frame_input(*this, frame); }

TeamInputs sensor_inputs(const Dataset& dataset) {
  TeamInputs team;
  team.name = dataset.name;
  team.sensor = dataset.sensor;
  team.camera = dataset.camera;
  team.object_ids = dataset.object_ids;
  team.start_poses = dataset.start_poses;
  team.robots.reserve(dataset.robots.size());
  for (const RobotData& robot : dataset.robots) {
    RobotInputs inputs;
    inputs.index = robot.index;
    if (dataset.start_poses == StartPoses::kKnown && !robot.groundtruth.empty()) {
      inputs.T_world_body_start = robot.groundtruth.front();
    }
    inputs.odometry = robot.odometry;
    inputs.objects = robot.objects;
    inputs.has_object_classes = robot.has_object_classes;
    inputs.object_classes = robot.object_classes;
    inputs.object_classes.resize(robot.objects.size());
    inputs.features = robot.features;
    inputs.odometry_covariance = robot.odometry_covariance;
    team.robots.push_back(std::move(inputs));
  }
  return team;
}

Dataset make_variant(const Dataset& dataset, bool private_ids, bool unknown_starts) {
  Dataset variant = dataset;
  if (unknown_starts) variant.start_poses = StartPoses::kUnknown;
  if (!private_ids) return variant;
  variant.object_ids = ObjectIds::kPrivate;
  for (RobotData& robot : variant.robots) {
    // The truth of an id as the dataset has it: a global id is its own truth when it has ground
    // truth (or no ground truth is given at all), a private id goes through the truth map.
    const auto truth_of = [&](LandmarkId id) {
      if (dataset.object_ids == ObjectIds::kPrivate) {
        const auto found = robot.object_truth_ids.find(id);
        return found == robot.object_truth_ids.end() ? kNoTruthId : found->second;
      }
      if (dataset.objects_groundtruth.empty() || dataset.objects_groundtruth.contains(id)) {
        return id;
      }
      return kNoTruthId;
    };
    std::map<LandmarkId, LandmarkId> private_of;
    std::map<LandmarkId, LandmarkId> truth_ids;
    for (auto& frame : robot.objects) {
      std::vector<LandmarkId> ids;
      for (const StereoObservation& observation : frame) ids.push_back(observation.id);
      std::sort(ids.begin(), ids.end());
      for (LandmarkId id : ids) {
        if (private_of.contains(id)) continue;
        const auto next = static_cast<LandmarkId>(private_of.size());
        private_of[id] = next;
        truth_ids[next] = truth_of(id);
      }
      for (StereoObservation& observation : frame) observation.id = private_of.at(observation.id);
    }
    robot.object_truth_ids = std::move(truth_ids);
    robot.has_object_truth_ids = true;
  }
  return variant;
}

}  // namespace concord::dataset
