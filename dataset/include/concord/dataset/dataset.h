#pragma once
/// \file
/// Reader and writer of the shared plain-text multi-robot dataset layout (see
/// shared/datasets/README.md):
///
///     <dataset>/dataset.json        camera model and facts about the set
///     <dataset>/objects_gt.csv      id,x,y,z   ground-truth object positions (optional)
///     <dataset>/robot_NN/groundtruth.kitti   N poses T_world_body
///     <dataset>/robot_NN/odometry.kitti      N-1 poses T_body(k-1)_body(k)
///     <dataset>/robot_NN/objects.csv         frame,id,u_left,v_left,u_right,v_right[,class]
///     <dataset>/robot_NN/features.csv        same columns, point-feature tracks (optional)
///     <dataset>/robot_NN/object_ids_truth.csv  id,truth_id (private ids only; evaluation only)
///
/// dataset.json "object_ids" says whether object ids are global (the same id is the same object
/// for every robot, data association given) or private (each robot names its objects its own way;
/// object_ids_truth.csv maps them to objects_gt.csv for evaluation), "start_poses" whether the
/// robots' first ground-truth poses are known to them (their filters start there, in the world
/// frame) or unknown (each filter starts at the identity of its own frame). Defaults: global and
/// known. What a robot may use online is TeamInputs (sensor_inputs()): never the ground truth.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <filesystem>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "concord/estimator/types.h"

namespace concord::dataset {

/// Thrown on bad input; what() names the file and (where relevant) the 1-based line and what is
/// wrong, as "<file>:<line>: <problem>".
class DatasetError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// dataset.json "object_ids".
enum class ObjectIds { kGlobal, kPrivate };
/// dataset.json "start_poses".
enum class StartPoses { kKnown, kUnknown };

/// "global" / "private", "known" / "unknown".
std::string to_string(ObjectIds object_ids);
std::string to_string(StartPoses start_poses);

/// Truth id of a detection of no real object (a false detection) in object_ids_truth.csv.
inline constexpr LandmarkId kNoTruthId = -1;

/// Everything one robot recorded, and its ground truth (for evaluation).
struct RobotData {
  /// The NN of the robot_NN folder.
  int index = 0;
  /// T_world_body per frame (N entries).
  std::vector<Eigen::Isometry3d> groundtruth;
  /// T_body(k-1)_body(k): entry k-1 is the measured motion from frame k-1 to frame k (N-1 entries).
  std::vector<Eigen::Isometry3d> odometry;
  /// Object observations per frame (N entries), in image units as in the file.
  std::vector<std::vector<StereoObservation>> objects;
  /// Point-feature observations per frame (N entries); empty vectors when there is no
  /// features.csv.
  std::vector<std::vector<StereoObservation>> features;
  /// Whether features.csv was present (and loaded).
  bool has_features = false;
  /// Covariance of each odometry entry's right perturbation [rho; phi] where the odometry
  /// reported one (optional odometry_covariance.csv, the columns of pose_covariance.csv; row
  /// `frame` k is the motion k-1 -> k): N-1 entries, or empty without the file. Frames without
  /// a row use the estimator's configured odometry noise.
  std::vector<std::optional<Eigen::Matrix<double, 6, 6>>> odometry_covariance;
  /// Detector class of each object observation, parallel to `objects` (objects.csv's optional
  /// `class` column, an integer >= 0); empty vectors when the column is absent.
  std::vector<std::vector<int>> object_classes;
  /// Whether objects.csv had a class column.
  bool has_object_classes = false;
  /// Private object id -> id in objects_gt.csv (kNoTruthId for a false detection), from
  /// object_ids_truth.csv. Evaluation only: never part of what a robot uses (TeamInputs).
  std::map<LandmarkId, LandmarkId> object_truth_ids;
  /// Whether object_ids_truth.csv was present (and loaded).
  bool has_object_truth_ids = false;

  /// N, the number of frames (ground-truth poses).
  int num_frames() const;
  /// FrameInput for frame k: odometry k-1 -> k (absent at k = 0), objects, features.
  /// Throws std::out_of_range unless 0 <= frame < num_frames().
  FrameInput frame_input(int frame) const;
};

/// A whole multi-robot dataset in memory.
struct Dataset {
  /// dataset.json "name" (or the folder name if absent).
  std::string name;
  /// dataset.json "sensor": which sensor recorded it, naming its estimator config
  /// (configs/sensors/<sensor>.yaml); empty when absent.
  std::string sensor;
  /// The folder the dataset was read from (as given to read_dataset).
  std::filesystem::path root;
  /// From dataset.json "camera": K, T_cam_body -> T_cam0_body, T_cam0_cam1.
  StereoCamera camera;
  /// Ground-truth object positions in the world frame, from objects_gt.csv (empty when the file
  /// is absent).
  std::map<LandmarkId, Eigen::Vector3d> objects_groundtruth;
  /// robot_00, robot_01, ... in order.
  std::vector<RobotData> robots;
  /// dataset.json "object_ids" (default global).
  ObjectIds object_ids = ObjectIds::kGlobal;
  /// dataset.json "start_poses" (default known).
  StartPoses start_poses = StartPoses::kKnown;
};

/// What one robot may use online: its own measurements and, only when the dataset's start poses
/// are known, its start pose. No ground truth, no truth ids (structurally: the replay and the
/// negotiation get this, the evaluation gets the Dataset).
struct RobotInputs {
  int index = 0;
  /// T_world_body of frame 0 when start poses are known; nullopt when unknown (the filter starts
  /// at the identity of the robot's own frame).
  std::optional<Eigen::Isometry3d> T_world_body_start;
  /// As RobotData (N - 1 odometry entries, N frames of observations).
  std::vector<Eigen::Isometry3d> odometry;
  std::vector<std::vector<StereoObservation>> objects;
  /// Parallel to objects; empty vectors when there is no class column.
  std::vector<std::vector<int>> object_classes;
  bool has_object_classes = false;
  std::vector<std::vector<StereoObservation>> features;
  /// As RobotData::odometry_covariance (N - 1 entries or empty).
  std::vector<std::optional<Eigen::Matrix<double, 6, 6>>> odometry_covariance;

  int num_frames() const { return static_cast<int>(odometry.size()) + 1; }
  /// FrameInput for frame k (see RobotData::frame_input).
  FrameInput frame_input(int frame) const;
};

/// What a whole team may use online.
struct TeamInputs {
  std::string name;
  std::string sensor;
  StereoCamera camera;
  ObjectIds object_ids = ObjectIds::kGlobal;
  StartPoses start_poses = StartPoses::kKnown;
  std::vector<RobotInputs> robots;
};

/// The sensor view of a dataset: measurements, classes, the start pose only when known.
TeamInputs sensor_inputs(const Dataset& dataset);

/// The variant of a dataset with private object ids and/or unknown start poses (`concord convert`,
/// `concord sim --private-ids --unknown-start`). Private ids: robot i's ids are renumbered 0, 1,
/// ... in the order it first observes them (ties by id), and object_truth_ids maps them to the
/// original global ids (a dataset already private is composed with its truth map). Unknown starts
/// only changes the flag (ground truth stays in the world frame). Point features are untouched.
Dataset make_variant(const Dataset& dataset, bool private_ids, bool unknown_starts);

/// What read_dataset loads.
struct ReadOptions {
  /// Keep only frames < max_frames (observations of later frames are dropped, odometry is cut to
  /// max_frames - 1 entries). Must be >= 1 when set.
  std::optional<int> max_frames;
  /// Keep only the first max_robots robots. Must be >= 1 when set.
  std::optional<int> max_robots;
  /// Read features.csv where present.
  bool load_features = true;
  /// Read odometry_covariance.csv where present.
  bool load_odometry_covariance = true;
  /// Read only robot_<only_robot> (a daemon replaying its own folder): Dataset::robots then holds
  /// that one robot, with RobotData::index = only_robot. DatasetError if the folder does not
  /// exist; std::invalid_argument if negative. max_robots is ignored when set.
  std::optional<int> only_robot;
};

/// Reads and validates a dataset folder. Throws DatasetError on any missing or malformed file,
/// std::invalid_argument on max_frames or max_robots < 1.
Dataset read_dataset(const std::filesystem::path& directory, const ReadOptions& options = {});

/// The folder of robot `index`: robot_00, robot_01, ..., robot_100 (the replay and launch output
/// layout uses the same names).
std::string robot_folder_name(int index);

/// The stereo camera of a dataset.json file (its "camera" object), checked as read_dataset
/// checks it. Throws DatasetError naming the file and the problem.
StereoCamera read_camera(const std::filesystem::path& dataset_json);

/// How a dataset names its objects and places its robots' starts.
struct Conventions {
  ObjectIds object_ids = ObjectIds::kGlobal;
  StartPoses start_poses = StartPoses::kKnown;
};

/// dataset.json's "object_ids" and "start_poses" (defaults where absent), checked as read_dataset
/// checks them; nothing else of the file is needed. Throws DatasetError naming the file and the
/// problem.
Conventions read_conventions(const std::filesystem::path& dataset_json);

/// Writes a dataset in the same layout (dataset.json, objects_gt.csv, robot_XX/{groundtruth.kitti,
/// odometry.kitti, objects.csv[, features.csv]}), creating the folder if needed and replacing each
/// file atomically. Numbers are written in their shortest exact form, so read_dataset gives back
/// the same values bit for bit. Robot i goes to robot_<i> whatever its index. Used to cut slices
/// and by the simulator. Throws std::invalid_argument on inconsistent robot data, DatasetError if
/// the folder holds robot folders beyond the ones written (they would be read back as robots), and
/// std::runtime_error if a file cannot be written.
void write_dataset(const Dataset& dataset, const std::filesystem::path& directory);

/// Copy of a dataset cut to the first `frames` frames and the first `robots` robots (objects_gt
/// kept whole). Counts larger than available keep everything; counts < 1 throw
/// std::invalid_argument.
Dataset slice(const Dataset& dataset, int frames, int robots);

}  // namespace concord::dataset
