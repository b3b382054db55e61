#include "concord/dataset/result_io.h"

#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdio>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <set>
#include <stdexcept>
#include <string_view>
#include <system_error>

#include "text_parsing.h"

namespace concord::dataset {

namespace {

constexpr std::array<std::string_view, 10> kObjectEstimateColumns{
    "id", "x", "y", "z", "cxx", "cxy", "cxz", "cyy", "cyz", "czz"};
constexpr std::array<std::string_view, 1> kTeamIdColumn{"team_id"};

/// (row, column) of the covariance entries in the order of the columns cxx ... czz.
constexpr std::array<std::pair<int, int>, 6> kCovarianceUpperTriangle{
    {{0, 0}, {0, 1}, {0, 2}, {1, 1}, {1, 2}, {2, 2}}};

constexpr std::array<std::string_view, 22> kPoseCovarianceColumns{
    "frame", "c00", "c01", "c02", "c03", "c04", "c05", "c11", "c12", "c13", "c14",
    "c15",   "c22", "c23", "c24", "c25", "c33", "c34", "c35", "c44", "c45", "c55"};

/// A name in the folder of `file` that no other writer (process or thread) uses at the same time.
std::filesystem::path temporary_path_for(const std::filesystem::path& file) {
  static std::atomic<unsigned long> counter{0};
  const std::string name =
      text_parsing::concatenate({".", file.filename().string(), ".tmp.", std::to_string(::getpid()),
                                 ".", std::to_string(counter++)});
  return file.parent_path() / name;
}

}  // namespace

void write_file_atomically(const std::filesystem::path& file, const std::string& content) {
  const std::filesystem::path temporary = temporary_path_for(file);
  const auto fail = [&](const std::string& problem) {
    std::error_code ignored;
    std::filesystem::remove(temporary, ignored);
    throw std::runtime_error(file.string() + ": cannot write: " + problem);
  };
  {
    std::ofstream stream(temporary, std::ios::binary | std::ios::trunc);
    if (!stream) fail("cannot create " + temporary.string());
    stream.write(content.data(), static_cast<std::streamsize>(content.size()));
    stream.close();
    if (!stream) fail("write error on " + temporary.string());
  }
  std::error_code error;
  std::filesystem::rename(temporary, file, error);
  if (error) fail("cannot rename " + temporary.string() + ": " + error.message());
}

std::string format_trajectory_kitti(const std::vector<Eigen::Isometry3d>& poses) {
  return text_parsing::format_kitti_poses(poses);
}

std::string format_trajectory_tum(const std::vector<double>& times,
                                  const std::vector<Eigen::Isometry3d>& poses) {
  std::string text;
  char line[256];
  const std::size_t count = std::min(times.size(), poses.size());
  for (std::size_t i = 0; i < count; ++i) {
    const Eigen::Isometry3d& T = poses[i];
    const Eigen::Quaterniond q(T.rotation());
    std::snprintf(line, sizeof line, "%.9f %.17g %.17g %.17g %.17g %.17g %.17g %.17g\n", times[i],
                  T.translation().x(), T.translation().y(), T.translation().z(), q.x(), q.y(),
                  q.z(), q.w());
    text += line;
  }
  return text;
}

void write_trajectory_kitti(const std::filesystem::path& file,
                            const std::vector<Eigen::Isometry3d>& poses) {
  write_file_atomically(file, format_trajectory_kitti(poses));
}

std::vector<Eigen::Isometry3d> read_trajectory_kitti(const std::filesystem::path& file) {
  return text_parsing::read_kitti_poses(file);
}

namespace {

std::string format_objects(const std::vector<ObjectEstimate>& objects,
                           const std::vector<LandmarkId>* team_ids) {
  std::vector<std::size_t> order(objects.size());
  for (std::size_t n = 0; n < order.size(); ++n) order[n] = n;
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return objects[a].id < objects[b].id; });

  std::string out = text_parsing::csv_header(kObjectEstimateColumns);
  if (team_ids != nullptr) out += "," + std::string(kTeamIdColumn[0]);
  out += '\n';
  for (const std::size_t n : order) {
    const ObjectEstimate* object = &objects[n];
    text_parsing::append_integer(out, object->id);
    for (int axis = 0; axis < 3; ++axis) {
      out += ',';
      text_parsing::append_number(out, object->p_world[axis]);
    }
    for (const auto& [row, column] : kCovarianceUpperTriangle) {
      out += ',';
      text_parsing::append_number(out, object->covariance(row, column));
    }
    if (team_ids != nullptr) {
      out += ',';
      text_parsing::append_integer(out, (*team_ids)[n]);
    }
    out += '\n';
  }
  return out;
}

}  // namespace

void write_objects_csv(const std::filesystem::path& file,
                       const std::vector<ObjectEstimate>& objects) {
  write_file_atomically(file, format_objects(objects, nullptr));
}

void write_objects_csv(const std::filesystem::path& file,
                       const std::vector<ObjectEstimate>& objects,
                       const std::vector<LandmarkId>& team_ids) {
  if (team_ids.size() != objects.size()) {
    throw std::invalid_argument("write_objects_csv: " + std::to_string(team_ids.size()) +
                                " team ids for " + std::to_string(objects.size()) + " objects");
  }
  write_file_atomically(file, format_objects(objects, &team_ids));
}

std::vector<ObjectEstimate> read_objects_csv(const std::filesystem::path& file,
                                             std::vector<LandmarkId>* team_ids) {
  std::vector<ObjectEstimate> objects;
  std::set<LandmarkId> seen;
  text_parsing::CsvReader table(file, kObjectEstimateColumns, kTeamIdColumn);
  if (team_ids != nullptr) team_ids->clear();
  while (table.next_row()) {
    if (team_ids != nullptr && table.has_optional_columns()) {
      team_ids->push_back(table.integer(kObjectEstimateColumns.size()));
    }
    ObjectEstimate object;
    object.id = table.integer(0);
    if (!seen.insert(object.id).second) table.fail("duplicate id " + std::to_string(object.id));
    object.p_world = Eigen::Vector3d(table.number(1), table.number(2), table.number(3));
    for (std::size_t entry = 0; entry < kCovarianceUpperTriangle.size(); ++entry) {
      const auto [row, column] = kCovarianceUpperTriangle[entry];
      const double value = table.number(4 + entry);
      object.covariance(row, column) = value;
      object.covariance(column, row) = value;
    }
    objects.push_back(object);
  }
  return objects;
}

std::string format_pose_covariances_csv(const std::vector<PoseCovariance>& covariances) {
  std::string out = text_parsing::csv_header(kPoseCovarianceColumns) + '\n';
  for (const PoseCovariance& entry : covariances) {
    text_parsing::append_integer(out, entry.frame);
    for (int row = 0; row < 6; ++row) {
      for (int column = row; column < 6; ++column) {
        out += ',';
        text_parsing::append_number(out, entry.covariance(row, column));
      }
    }
    out += '\n';
  }
  return out;
}

void write_pose_covariances_csv(const std::filesystem::path& file,
                                const std::vector<PoseCovariance>& covariances) {
  write_file_atomically(file, format_pose_covariances_csv(covariances));
}

std::vector<PoseCovariance> read_pose_covariances_csv(const std::filesystem::path& file) {
  std::vector<PoseCovariance> covariances;
  text_parsing::CsvReader table(file, kPoseCovarianceColumns);
  while (table.next_row()) {
    PoseCovariance entry;
    const std::int64_t frame = table.integer(0);
    if (frame < 0 || frame > std::numeric_limits<int>::max()) {
      table.fail("frame " + std::to_string(frame) + " out of range");
    }
    entry.frame = static_cast<int>(frame);
    std::size_t column_index = 1;
    for (int row = 0; row < 6; ++row) {
      for (int column = row; column < 6; ++column) {
        const double value = table.number(column_index++);
        entry.covariance(row, column) = value;
        entry.covariance(column, row) = value;
      }
    }
    covariances.push_back(entry);
  }
  return covariances;
}

namespace {

nlohmann::ordered_json frame_robot_json(const std::optional<int>& robot) {
  return robot ? nlohmann::ordered_json(*robot) : nlohmann::ordered_json(nullptr);
}

}  // namespace

void write_alignment_json(const std::filesystem::path& file, const AlignmentRecord& record) {
  nlohmann::ordered_json root;
  root["team_frame_robot"] = frame_robot_json(record.team_frame_robot);
  root["aligned_at_frame"] = record.aligned_at_frame;
  root["moved"] = record.moved;
  nlohmann::ordered_json pose = nlohmann::ordered_json::array();
  for (int index = 0; index < 12; ++index)
    pose.push_back(record.T_team_own.matrix()(index / 4, index % 4));
  root["T_team_own"] = pose;
  nlohmann::ordered_json covariance = nlohmann::ordered_json::array();
  for (int row = 0; row < 6; ++row) {
    nlohmann::ordered_json values = nlohmann::ordered_json::array();
    for (int column = 0; column < 6; ++column) values.push_back(record.covariance(row, column));
    covariance.push_back(values);
  }
  root["covariance"] = covariance;
  nlohmann::ordered_json segments = nlohmann::ordered_json::array();
  for (const auto& [from_frame, robot] : record.segments) {
    segments.push_back({{"from_frame", from_frame}, {"frame_robot", frame_robot_json(robot)}});
  }
  root["segments"] = segments;
  write_file_atomically(file, root.dump(2) + "\n");
}

AlignmentRecord read_alignment_json(const std::filesystem::path& file) {
  const std::string text = text_parsing::read_whole_file(file);
  nlohmann::json root;
  try {
    root = nlohmann::json::parse(text);
  } catch (const nlohmann::json::parse_error& error) {
    text_parsing::fail_in_file(file, std::string("invalid JSON: ") + error.what());
  }
  const auto fail = [&](const std::string& key, const std::string& rule) {
    text_parsing::fail_in_file(file, "\"" + key + "\" " + rule);
  };
  if (!root.is_object()) text_parsing::fail_in_file(file, "expected a JSON object");
  const auto frame_robot = [&](const nlohmann::json& value, const std::string& key) {
    if (value.is_null()) return std::optional<int>();
    if (!value.is_number_integer() || value.get<int>() < 0) {
      fail(key, "must be a robot index or null (the world frame)");
    }
    return std::optional<int>(value.get<int>());
  };
  AlignmentRecord record;
  if (!root.contains("team_frame_robot")) fail("team_frame_robot", "is missing");
  record.team_frame_robot = frame_robot(root["team_frame_robot"], "team_frame_robot");
  if (!root.contains("aligned_at_frame") || !root["aligned_at_frame"].is_number_integer() ||
      root["aligned_at_frame"].get<int>() < 0) {
    fail("aligned_at_frame", "must be an integer >= 0");
  }
  record.aligned_at_frame = root["aligned_at_frame"].get<int>();
  if (root.contains("moved")) {
    if (!root["moved"].is_boolean()) fail("moved", "must be true or false");
    record.moved = root["moved"].get<bool>();
  }
  const nlohmann::json& pose = root.contains("T_team_own") ? root["T_team_own"] : nlohmann::json();
  if (!pose.is_array() || pose.size() != 12 ||
      !std::all_of(pose.begin(), pose.end(), [](const auto& v) { return v.is_number(); })) {
    fail("T_team_own", "must be 12 numbers (a KITTI pose line)");
  }
  for (int index = 0; index < 12; ++index) {
    record.T_team_own.matrix()(index / 4, index % 4) = pose[index].get<double>();
  }
  const std::string problem = text_parsing::check_and_orthonormalize_rotation(record.T_team_own);
  if (!problem.empty()) fail("T_team_own", problem);
  const nlohmann::json& covariance =
      root.contains("covariance") ? root["covariance"] : nlohmann::json();
  bool covariance_ok = covariance.is_array() && covariance.size() == 6;
  for (std::size_t row = 0; covariance_ok && row < 6; ++row) {
    covariance_ok = covariance[row].is_array() && covariance[row].size() == 6;
    for (std::size_t column = 0; covariance_ok && column < 6; ++column) {
      covariance_ok = covariance[row][column].is_number();
      if (covariance_ok) record.covariance(row, column) = covariance[row][column].get<double>();
    }
  }
  if (!covariance_ok) fail("covariance", "must be 6 rows of 6 numbers");
  if (root.contains("segments")) {
    const nlohmann::json& segments = root["segments"];
    if (!segments.is_array()) fail("segments", "must be an array");
    for (const auto& segment : segments) {
      if (!segment.is_object() || !segment.contains("from_frame") ||
          !segment["from_frame"].is_number_integer() || !segment.contains("frame_robot")) {
        fail("segments", "entries must be {\"from_frame\": K, \"frame_robot\": R or null}");
      }
      record.segments.emplace_back(segment["from_frame"].get<int>(),
                                   frame_robot(segment["frame_robot"], "segments.frame_robot"));
    }
  }
  return record;
}

}  // namespace concord::dataset
