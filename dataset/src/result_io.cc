#include "concord/dataset/result_io.h"

#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdio>
#include <fstream>
#include <limits>
#include <set>
#include <stdexcept>
#include <string_view>
#include <system_error>

#include "text_parsing.h"

namespace concord::dataset {

namespace {

constexpr std::array<std::string_view, 10> kObjectEstimateColumns{
    "id", "x", "y", "z", "cxx", "cxy", "cxz", "cyy", "cyz", "czz"};

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

void write_objects_csv(const std::filesystem::path& file,
                       const std::vector<ObjectEstimate>& objects) {
  std::vector<const ObjectEstimate*> sorted;
  sorted.reserve(objects.size());
  for (const ObjectEstimate& object : objects) sorted.push_back(&object);
  std::stable_sort(sorted.begin(), sorted.end(),
                   [](const ObjectEstimate* a, const ObjectEstimate* b) { return a->id < b->id; });

  std::string out = text_parsing::csv_header(kObjectEstimateColumns) + '\n';
  for (const ObjectEstimate* object : sorted) {
    text_parsing::append_integer(out, object->id);
    for (int axis = 0; axis < 3; ++axis) {
      out += ',';
      text_parsing::append_number(out, object->p_world[axis]);
    }
    for (const auto& [row, column] : kCovarianceUpperTriangle) {
      out += ',';
      text_parsing::append_number(out, object->covariance(row, column));
    }
    out += '\n';
  }
  write_file_atomically(file, out);
}

std::vector<ObjectEstimate> read_objects_csv(const std::filesystem::path& file) {
  std::vector<ObjectEstimate> objects;
  std::set<LandmarkId> seen;
  text_parsing::CsvReader table(file, kObjectEstimateColumns);
  while (table.next_row()) {
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

}  // namespace concord::dataset
