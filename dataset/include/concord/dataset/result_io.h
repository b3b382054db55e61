#pragma once
/// \file
/// Files of a result folder: estimated trajectories (KITTI pose format, as in the datasets, so
/// trajectory tools such as `evo` read them) and object estimates with their covariances (CSV).
/// Every writer replaces its file atomically, so a reader never sees a half-written file.

#include <Eigen/Geometry>
#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "concord/dataset/dataset.h"
#include "concord/estimator/types.h"

namespace concord::dataset {

/// Writes one pose per line: the top 3x4 block of the matrix, row-major, 12 numbers in their
/// shortest exact form. Throws std::runtime_error if the file cannot be written.
void write_trajectory_kitti(const std::filesystem::path& file,
                            const std::vector<Eigen::Isometry3d>& poses);

/// Reads a KITTI pose file; rotation blocks with small errors are re-orthonormalized. Throws
/// DatasetError on bad input (naming the file and line).
/// The text write_trajectory_kitti writes: one line of 12 numbers (3x4, row-major) per pose.
std::string format_trajectory_kitti(const std::vector<Eigen::Isometry3d>& poses);

std::vector<Eigen::Isometry3d> read_trajectory_kitti(const std::filesystem::path& file);

/// The TUM trajectory format: one line "t x y z qx qy qz qw" per pose, t in seconds (the frame's
/// time stamp). `times` and `poses` have the same length.
std::string format_trajectory_tum(const std::vector<double>& times,
                                  const std::vector<Eigen::Isometry3d>& poses);

/// Writes object estimates under the header "id,x,y,z,cxx,cxy,cxz,cyy,cyz,czz" (the upper
/// triangle of the covariance), one row per object, rows sorted by id. Throws std::runtime_error if
/// the file cannot be written.
void write_objects_csv(const std::filesystem::path& file,
                       const std::vector<ObjectEstimate>& objects);

/// As write_objects_csv, with a last column team_id (parallel to objects; -1 while unshared):
/// "id,x,y,z,cxx,cxy,cxz,cyy,cyz,czz,team_id". Throws std::invalid_argument if the sizes differ.
void write_objects_csv(const std::filesystem::path& file,
                       const std::vector<ObjectEstimate>& objects,
                       const std::vector<LandmarkId>& team_ids);

/// Reads a file written by write_objects_csv (the covariance is filled symmetrically), in file
/// order, with or without the team_id column (its values go to *team_ids when given; empty
/// without the column). Throws DatasetError on bad input (naming the file and line), including a
/// repeated id.
std::vector<ObjectEstimate> read_objects_csv(const std::filesystem::path& file,
                                             std::vector<LandmarkId>* team_ids = nullptr);

/// robot_XX/alignment.json: how a robot's estimates relate to its team frame.
struct AlignmentRecord {
  /// The robot whose start frame is the team frame; nullopt: the world frame (known starts).
  std::optional<int> team_frame_robot;
  /// The first frame from which the robot's trajectory.kitti is in the team frame (before it, in
  /// the frames listed in segments).
  int aligned_at_frame = 0;
  /// Whether the robot moved into another robot's frame (false for the team frame's own robot and
  /// for a robot that never aligned).
  bool moved = false;
  /// Maps the robot's own start frame into the team frame, with the covariance of its left
  /// perturbation (team frame), [rho; phi].
  Eigen::Isometry3d T_team_own = Eigen::Isometry3d::Identity();
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
  /// (first frame, frame robot or nullopt for the world) of each stretch of the trajectory in one
  /// frame, in order, the first from frame 0.
  std::vector<std::pair<int, std::optional<int>>> segments;
};

/// Writes alignment.json: {"team_frame_robot": R or null, "aligned_at_frame": K, "moved": b,
/// "T_team_own": [12 numbers, a KITTI line], "covariance": [6 rows of 6], "segments":
/// [{"from_frame": K, "frame_robot": R or null}, ...]}. Throws std::runtime_error if it cannot.
void write_alignment_json(const std::filesystem::path& file, const AlignmentRecord& record);

/// Reads alignment.json. Throws DatasetError naming the file and the bad key.
AlignmentRecord read_alignment_json(const std::filesystem::path& file);

/// Covariance of one pose estimate: the 6x6 covariance of the right perturbation xi = [rho; phi]
/// of T_world_body (T = T_hat exp(xi^)), at a frame.
struct PoseCovariance {
  int frame = 0;
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
};

/// The text of pose_covariance.csv: the header "frame,c00,c01,...,c05,c11,...,c55" (the 21
/// entries of the upper triangle, row by row), then one row per entry.
std::string format_pose_covariances_csv(const std::vector<PoseCovariance>& covariances);

/// Writes format_pose_covariances_csv atomically. Throws std::runtime_error if it cannot.
void write_pose_covariances_csv(const std::filesystem::path& file,
                                const std::vector<PoseCovariance>& covariances);

/// Reads pose_covariance.csv (the covariance filled symmetrically), in file order. Throws
/// DatasetError on bad input, naming the file and line.
std::vector<PoseCovariance> read_pose_covariances_csv(const std::filesystem::path& file);

/// Writes `content` to a temporary file in the same folder, then renames it over `file` (atomic
/// replace on POSIX file systems). The folder must exist. Throws std::runtime_error on failure,
/// leaving no temporary file behind.
void write_file_atomically(const std::filesystem::path& file, const std::string& content);

}  // namespace concord::dataset
