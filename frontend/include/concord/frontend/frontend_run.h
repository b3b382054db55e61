#pragma once
/// \file
/// `concord frontend`: runs the front-end over one stereo sequence or a team of them and writes a
/// dataset folder in the shared layout (docs/datasets.md) that `concord replay` and the daemons
/// read:
///
///     OUT/dataset.json          the rectified camera (K in pixels, T_cam_body, T_cam0_cam1)
///     OUT/objects_gt.csv        copied from the input folder when it has one
///     OUT/frontend.json         options, per-robot statistics, timings, noise estimates
///     OUT/estimator.yaml        an estimator config whose noise values are the front-end's own
///                               (suggested_estimator_options); `concord replay` uses it
///     OUT/robot_NN/groundtruth.kitti    the sequence's ground truth, or (without one) the
///                                       odometry integrated from the identity (a dead reckoning)
///     OUT/robot_NN/odometry.kitti       T_body(k-1)_body(k) from the visual (or given) odometry
///     OUT/robot_NN/odometry_covariance.csv   frame,valid,inliers, then the 21 upper-triangle
///                                       entries of its 6x6 covariance ([rho; phi], row-major)
///     OUT/robot_NN/features.csv         point-feature tracks (rectified pixels)
///     OUT/robot_NN/objects.csv          stereo object observations from the detections, with
///                                       the detector's class as a number (class column)
///     OUT/robot_NN/object_ids_truth.csv copied from a team input's robot_NN (private ids only)
///
/// The input is a sequence folder (EuRoC or KITTI layout; it becomes robot_00) or a folder of
/// robot_NN sequence folders (one robot each). A sequence's detections are `detections.csv` in its
/// folder unless given. OpenCV-free.

#include <Eigen/Core>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "concord/dataset/dataset.h"
#include "concord/estimator/options.h"
#include "concord/estimator/types.h"
#include "concord/frontend/frontend_options.h"
#include "concord/frontend/track_statistics.h"

namespace concord::frontend {

struct FrontendRunOptions {
  FrontendOptions frontend;
  /// Only the first max_frames frames of each sequence.
  std::optional<int> max_frames;
  /// Detections of a single-sequence input (default: <sequence>/detections.csv if present).
  std::filesystem::path detections;
  /// The robot's own odometry for a single-sequence input (a KITTI pose file of
  /// T_body(k-1)_body(k), one line per frame after the first) instead of visual odometry, with
  /// the standard deviations that become its covariance.
  std::filesystem::path odometry;
  double odometry_translation_sigma = 0.05;
  double odometry_rotation_sigma = 0.01;
  /// How the output's object ids and start poses are to be read (dataset.json "object_ids",
  /// "start_poses"). Unset: as the input team folder's dataset.json declares them; without one,
  /// a team's ids are private (a detector's track ids are its own robot's, and the robots
  /// negotiate which objects are the same) and its starts unknown; one sequence is global and
  /// known.
  std::optional<dataset::ObjectIds> object_ids;
  std::optional<dataset::StartPoses> start_poses;
  /// The body axis that points up when the robot stands level (+x, -x, +y, -y, +z, -z; for the
  /// KITTI layout's body, a forward-looking left camera, -y), written to estimator.yaml as
  /// association.start_up_axis: the negotiation then refuses an alignment that tilts one
  /// robot's start frame against another's; and when it is the left camera's vertical, objects
  /// are taken as upright in the camera's rows (ObjectOptions::upright). "unknown" (the default)
  /// does neither.
  std::string up_axis = "unknown";
  /// The team's detector class names (any order), the list a daemon's image source is given
  /// (source.classes): objects.csv's class column numbers them by it, so that robots processed
  /// in separate runs, and daemons, number the classes alike. A detected class not in it is an
  /// error. Empty: the names the run's detections use (frontend::ClassNumbering).
  std::vector<std::string> classes;
  /// The detector's error model (an estimator config fragment with the object noise keys only:
  /// object_noise, object_noise_constant, object_noise_persistent, object_noise_correlation,
  /// object_offset_sigma, object_offset_walk, object_displacement_sigma,
  /// object_displacement_walk, object_init_max_reprojection_error), and the point-feature
  /// tracks' drift measured with it (feature_drift_sigma), e.g. what `concord calibrate
  /// --detector-model` measured on a calibration segment: written into estimator.yaml in place
  /// of the isotropic objects.detection_sigma (and no drift), so that the dataset's config is
  /// the sensor's (camera, tracker and detector) whole. Empty: detection_sigma. Any other key
  /// is an error (the front-end measures the odometry and the white feature noise itself, which
  /// a calibration segment's ground truth cannot improve on: docs/frontend.md).
  std::filesystem::path detector_model;
  /// Each point-feature observation's own noise, from the tracker's alignment variances scaled
  /// by the robot's own tracks (ObservationNoise), written as features.csv's sigma_left and
  /// sigma_right. False: none (the estimator's feature_noise for every observation).
  bool observation_noise = true;
  /// dataset.json "name" of the output (replay uses the estimator.yaml written beside it).
  std::string name = "frontend";
  /// Called after each frame with (robot, frame, frames of that robot).
  std::function<void(int, int, int)> progress;
};

/// Percentiles of a per-frame sample.
struct Percentiles {
  double p50 = 0.0, p90 = 0.0, p99 = 0.0, max = 0.0, mean = 0.0;
};

/// What the front-end measured on one sequence.
struct SequenceSummary {
  std::string sequence;  ///< the input folder
  int frames = 0;
  /// Tracks per frame (mean and smallest), the mean over frames of the current tracks' lengths
  /// (frames), and the number of distinct tracks.
  double tracks_per_frame = 0.0;
  int min_tracks = 0;
  double mean_track_length = 0.0;
  long long distinct_tracks = 0;
  /// Tracks removed per frame on average by each check.
  double rejected_circular_per_frame = 0.0;
  double rejected_epipolar_per_frame = 0.0;
  double rejected_ransac_per_frame = 0.0;
  /// Anchored tracking: tracks anchored afresh (continued under a new id) per frame.
  double reanchored_per_frame = 0.0;
  double odometry_outliers_per_frame = 0.0;
  /// Frames whose motion could not be measured.
  int odometry_failures = 0;
  /// Median over frames of the odometry's standard deviations: sqrt of the mean of the three
  /// translation (rotation) variances, metres (radians).
  double odometry_translation_sigma = 0.0;
  double odometry_rotation_sigma = 0.0;
  /// Median over frames of the tracker's stereo-row noise estimate, pixels.
  double feature_pixel_sigma = 0.0;
  /// Noise of a track coordinate from the tracks' own consistency under the odometry
  /// (track_consistency), pixels: the value the estimator's feature_noise (per coordinate) should take.
  double feature_track_sigma = 0.0;
  /// The noise per observation written (FrontendRunOptions::observation_noise; not valid when
  /// off or when too few alignments measured it).
  ObservationNoise observation_noise;
  /// Detections, the observations made from them, and the detections refused for an ambiguous or
  /// left-right inconsistent stereo match.
  long long detections = 0;
  long long objects_observed = 0;
  long long objects_ambiguous = 0;
  long long objects_inconsistent = 0;
  /// Per-frame milliseconds: total (wall, and the thread's CPU time with and without loading the
  /// images) and each stage (wall).
  Percentiles total_ms, total_cpu_ms, processing_cpu_ms, load_ms, rectify_ms, track_ms, odometry_ms,
      objects_ms;
};

struct FrontendRunSummary {
  std::vector<SequenceSummary> robots;
  /// What the output's dataset.json says of its object ids and start poses
  /// (FrontendRunOptions::object_ids, start_poses).
  dataset::ObjectIds object_ids = dataset::ObjectIds::kGlobal;
  dataset::StartPoses start_poses = dataset::StartPoses::kKnown;
  /// The detectors' class names in the order of the class numbers written to objects.csv; empty
  /// when the names were numbers already (written as they are) or there were no detections.
  std::vector<std::string> classes;
};

/// Runs the front-end on `input` and writes the dataset to `out` (created if needed). Throws
/// FrontendError on bad input (naming the file), dataset::DatasetError if `out` holds more robot
/// folders than written.
[[nodiscard]] FrontendRunSummary run_frontend(const std::filesystem::path& input,
                                              const std::filesystem::path& out,
                                              const FrontendRunOptions& options);

/// Estimator options for a front-end's dataset, noise values from the front-end and the sensor
/// (docs/frontend.md): odometry sigmas = the median over robots of the odometry's reported
/// standard deviations, feature_noise = the median of the tracks' consistency estimate,
/// object_noise = ObjectOptions::detection_sigma (isotropic), sanity limits at 3 and 4 sigma,
/// depth limits from fx * baseline (features out to 1 pixel of disparity, objects to 5).
EstimatorOptions suggested_estimator_options(const FrontendRunSummary& summary,
                                             const StereoCamera& camera,
                                             const FrontendOptions& options);

/// The sequence folders of an input: the input itself if it is a sequence, else its robot_NN
/// sub-folders in order. Throws FrontendError if there are none.
[[nodiscard]] std::vector<std::filesystem::path> list_sequences(const std::filesystem::path& input);

}  // namespace concord::frontend
