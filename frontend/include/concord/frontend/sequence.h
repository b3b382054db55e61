#pragma once
/// \file
/// Stereo image sequences on disk and their calibration, in the two layouts the front-end reads
/// (docs/frontend.md):
///
/// - EuRoC ASL (`mav0/cam0`, `mav0/cam1`: `data.csv` with `#timestamp [ns],filename` rows,
///   `data/<file>.png`, `sensor.yaml` with pinhole `intrinsics` [fu, fv, cu, cv],
///   `distortion_model: radial-tangential`, `distortion_coefficients` [k1, k2, p1, p2],
///   `resolution` and `T_BS`, the pose of the camera in the body frame). Optional ground truth in
///   `mav0/state_groundtruth_estimate0/data.csv` (T_world_body as position and quaternion w,x,y,z).
/// - KITTI odometry (`image_0/`, `image_1/` with `%06d.png`, `calib.txt` with the rectified
///   projection matrices `P0:` and `P1:`, `times.txt` with one time in seconds a line). Optional
///   ground truth in `poses.txt` (KITTI pose lines, T_world_cam0). The body is the left camera.
///
/// Reading checks everything that can be checked without decoding an image: every image file
/// exists, left and right time stamps match, the calibration is usable. Problems are reported as
/// FrontendError with the file (and line or key) named. The sequence holds paths, not pixels:
/// the front-end loads each image when it processes the frame.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <filesystem>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace concord::frontend {

/// Bad input to the front-end (a file, a calibration, a detection table, an option). what()
/// names the file and, where there is one, the line or key: "<file>:<line>: <problem>".
class FrontendError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// One camera of a stereo pair as calibrated (before rectification).
struct CameraIntrinsics {
  /// Focal lengths and principal point, pixels.
  double fx = 0.0, fy = 0.0, cx = 0.0, cy = 0.0;
  /// Radial-tangential distortion (k1, k2, p1, p2), OpenCV's order; zeros for rectified input.
  Eigen::Vector4d distortion = Eigen::Vector4d::Zero();
  /// Image size in pixels.
  int width = 0, height = 0;

  Eigen::Matrix3d K() const;
};

/// The calibration of a stereo pair as read from the sequence's files.
struct StereoRig {
  CameraIntrinsics left;
  CameraIntrinsics right;
  /// Pose of the right camera in the left camera frame (p_cam0 = T_cam0_cam1 * p_cam1).
  Eigen::Isometry3d T_cam0_cam1 = Eigen::Isometry3d::Identity();
  /// Maps body coordinates into the left optical frame (p_cam0 = T_cam0_body * p_body).
  Eigen::Isometry3d T_cam0_body = Eigen::Isometry3d::Identity();
  /// True when the images are already undistorted and rectified (KITTI): the front-end then
  /// uses them as they are.
  bool rectified = false;

  /// Every problem that makes the rig unusable for stereo (non-positive focal lengths, a
  /// principal point outside the image, image sizes that differ, a baseline under 1 mm, a right
  /// camera that is not beside the left one, non-finite numbers), each a sentence; empty if
  /// usable.
  [[nodiscard]] std::vector<std::string> problems() const;
};

enum class SequenceLayout { kEuroc, kKitti };

/// A stereo image sequence: calibration, time stamps, image files and optional ground truth.
struct StereoSequence {
  SequenceLayout layout = SequenceLayout::kKitti;
  /// The folder given to read_stereo_sequence.
  std::filesystem::path root;
  StereoRig rig;
  /// Time of each frame, seconds.
  std::vector<double> timestamps;
  std::vector<std::filesystem::path> left_images;
  std::vector<std::filesystem::path> right_images;
  /// T_world_body per frame when the sequence carries ground truth.
  std::optional<std::vector<Eigen::Isometry3d>> groundtruth;

  int num_frames() const { return static_cast<int>(timestamps.size()); }
};

/// What read_stereo_sequence accepts.
struct SequenceReadOptions {
  /// Keep only the first max_frames frames (must be >= 1 when set).
  std::optional<int> max_frames;
  /// EuRoC: largest difference between a left and a right time stamp, and between an image and
  /// its ground-truth sample, nanoseconds.
  std::int64_t max_time_difference_ns = 1000;
};

/// Reads the sequence in `folder`: EuRoC if it holds `mav0/` (or is a `mav0` folder with
/// `cam0/`), KITTI if it holds `calib.txt`. Throws FrontendError on any problem.
[[nodiscard]] StereoSequence read_stereo_sequence(const std::filesystem::path& folder,
                                                  const SequenceReadOptions& options = {});

/// Reads an EuRoC ASL sequence; `folder` holds `mav0/` or is it. Throws FrontendError.
[[nodiscard]] StereoSequence read_euroc_sequence(const std::filesystem::path& folder,
                                                 const SequenceReadOptions& options = {});

/// Reads a KITTI odometry sequence folder. Throws FrontendError.
[[nodiscard]] StereoSequence read_kitti_sequence(const std::filesystem::path& folder,
                                                 const SequenceReadOptions& options = {});

/// Whether `folder` looks like a sequence in either layout (without reading it).
bool is_stereo_sequence(const std::filesystem::path& folder);

/// Writes the calibration of a rectified pinhole stereo pair as a KITTI `calib.txt` (P0 and P1,
/// 12 numbers each): P0 = [K | 0], P1 = [K | -fx * baseline, 0, 0].
std::string format_kitti_calibration(const Eigen::Matrix3d& K, double baseline);

}  // namespace concord::frontend
