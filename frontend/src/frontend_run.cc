#include "concord/frontend/frontend_run.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <numbers>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <string>

#include "concord/config/options_file.h"
#include "concord/config/yaml_section.h"
#include "concord/dataset/dataset.h"
#include "concord/dataset/result_io.h"
#include "concord/frontend/frontend.h"
#include "concord/frontend/track_statistics.h"
#include "options_fields.h"
#include "sample_median.h"
#include "text_lines.h"

namespace concord::frontend {

namespace fs = std::filesystem;

namespace {

/// The least point-feature noise the front-end writes, pixels: a floor that keeps a perfectly
/// static or texture-poor sequence from claiming none.
constexpr double kMinFeatureSigma = 0.05;

Percentiles percentiles_of(std::vector<double> values) {
  Percentiles result;
  if (values.empty()) return result;
  std::sort(values.begin(), values.end());
  const auto at = [&](double p) {
    const auto rank = static_cast<std::size_t>(std::ceil(p / 100.0 * values.size()));
    return values[std::clamp<std::size_t>(rank, 1, values.size()) - 1];
  };
  result.p50 = at(50);
  result.p90 = at(90);
  result.p99 = at(99);
  result.max = values.back();
  double sum = 0.0;
  for (const double value : values) sum += value;
  result.mean = sum / values.size();
  return result;
}



nlohmann::ordered_json percentiles_json(const Percentiles& p) {
  return {{"p50", p.p50}, {"p90", p.p90}, {"p99", p.p99}, {"max", p.max}, {"mean", p.mean}};
}

nlohmann::ordered_json options_json(const FrontendOptions& options) {
  nlohmann::ordered_json document;
  visit_option_fields(options, [&](const char* section, const char* key, const auto& field) {
    document[section][key] = field;
  });
  return document;
}

/// The noise per observation's scales, or null when none was written.
nlohmann::ordered_json observation_noise_json(const ObservationNoise& noise) {
  if (!noise.valid()) return nullptr;
  return {{"scale_left", noise.scale_left},
          {"scale_stereo", noise.scale_stereo},
          {"typical_left_variance", noise.typical_left},
          {"typical_stereo_variance", noise.typical_stereo},
          {"observations", noise.observations}};
}

nlohmann::ordered_json summary_json(const SequenceSummary& s) {
  return {{"sequence", s.sequence},
          {"frames", s.frames},
          {"tracks_per_frame", s.tracks_per_frame},
          {"min_tracks", s.min_tracks},
          {"mean_track_length", s.mean_track_length},
          {"distinct_tracks", s.distinct_tracks},
          {"rejected_circular_per_frame", s.rejected_circular_per_frame},
          {"rejected_epipolar_per_frame", s.rejected_epipolar_per_frame},
          {"rejected_ransac_per_frame", s.rejected_ransac_per_frame},
          {"reanchored_per_frame", s.reanchored_per_frame},
          {"odometry_outliers_per_frame", s.odometry_outliers_per_frame},
          {"odometry_failures", s.odometry_failures},
          {"odometry_translation_sigma", s.odometry_translation_sigma},
          {"odometry_rotation_sigma", s.odometry_rotation_sigma},
          {"feature_pixel_sigma", s.feature_pixel_sigma},
          {"feature_track_sigma", s.feature_track_sigma},
          {"observation_noise", observation_noise_json(s.observation_noise)},
          {"detections", s.detections},
          {"objects_observed", s.objects_observed},
          {"objects_ambiguous", s.objects_ambiguous},
          {"objects_inconsistent", s.objects_inconsistent},
          {"milliseconds_per_frame",
           {{"total", percentiles_json(s.total_ms)},
            {"total_cpu", percentiles_json(s.total_cpu_ms)},
            {"processing_cpu", percentiles_json(s.processing_cpu_ms)},
            {"load", percentiles_json(s.load_ms)},
            {"rectify", percentiles_json(s.rectify_ms)},
            {"track", percentiles_json(s.track_ms)},
            {"odometry", percentiles_json(s.odometry_ms)},
            {"objects", percentiles_json(s.objects_ms)}}}};
}

bool same_camera(const StereoCamera& a, const StereoCamera& b) {
  return a.K.isApprox(b.K, 1e-9) && a.T_cam0_body.isApprox(b.T_cam0_body, 1e-9) &&
         a.T_cam0_cam1.isApprox(b.T_cam0_cam1, 1e-9);
}

/// One robot: the front-end over its sequence, as dataset robot data plus what was measured.
struct RobotRun {
  dataset::RobotData data;
  /// The detector's class name of each object observation, parallel to data.objects.
  std::vector<std::vector<std::string>> class_names;
  std::vector<MotionEstimate> motions;
  SequenceSummary summary;
  StereoCamera camera;
};

/// objects.csv's class column of every robot from the detectors' class names (`names`, per robot
/// and frame, parallel to its objects), numbered by ClassNumbering over the team's list when one
/// is given (a name not in it throws), else over every name the run's robots use; returns the
/// names in number order (empty when the names are numbers). No class column without object
/// observations.
std::vector<std::string> number_classes(
    const std::vector<std::vector<std::vector<std::string>>>& names,
    const std::vector<std::string>& team_classes, std::vector<dataset::RobotData>& robots) {
  std::vector<std::string> all;
  for (const auto& robot : names)
    for (const auto& frame : robot) all.insert(all.end(), frame.begin(), frame.end());
  if (all.empty()) return {};
  const ClassNumbering numbering(team_classes.empty() ? all : team_classes);
  numbering.require_all(all, "detections");
  for (std::size_t robot = 0; robot < robots.size(); ++robot) {
    robots[robot].has_object_classes = true;
    robots[robot].object_classes.clear();
    for (const auto& frame : names[robot]) {
      std::vector<int> classes;
      for (const std::string& name : frame) classes.push_back(*numbering.number(name));
      robots[robot].object_classes.push_back(std::move(classes));
    }
  }
  return numbering.numbered_names();
}

/// The front-end's options for a rig: objects are upright in the camera's rows when the robot's
/// up axis (a body axis, or "unknown") is the left camera's vertical within 10 degrees.
FrontendOptions options_for_rig(const FrontendOptions& options, const std::string& up_axis,
                                const Eigen::Isometry3d& T_cam0_body) {
  FrontendOptions out = options;
  const std::array<double, 3> axis = body_axis_vector(up_axis);  // zero for "unknown"
  const Eigen::Vector3d up_camera =
      T_cam0_body.linear() * Eigen::Vector3d(axis[0], axis[1], axis[2]);
  if (up_camera.norm() > 0.0 &&
      std::abs(up_camera.y()) >= std::cos(10.0 * std::numbers::pi / 180.0) * up_camera.norm()) {
    out.objects.upright = true;
  }
  return out;
}

RobotRun run_sequence(const fs::path& folder, int robot, bool single,
                      const FrontendRunOptions& options) {
  SequenceReadOptions read_options;
  read_options.max_frames = options.max_frames;
  StereoSequence sequence = read_stereo_sequence(folder, read_options);
  const int frames = sequence.num_frames();

  std::vector<std::vector<Detection>> detections;
  const fs::path detections_file =
      single && !options.detections.empty() ? options.detections : folder / "detections.csv";
  if (fs::exists(detections_file) || (single && !options.detections.empty())) {
    detections = read_detections(detections_file, frames, options.max_frames.has_value());
  }
  std::unique_ptr<OdometrySource> odometry;
  if (single && !options.odometry.empty()) {
    auto given = std::make_unique<FileOdometry>(FileOdometry::read(
        options.odometry, options.odometry_translation_sigma, options.odometry_rotation_sigma));
    if (given->size() < frames - 1) {
      throw FrontendError(options.odometry.string() + ": " + std::to_string(given->size()) +
                          " motions, the sequence needs " + std::to_string(frames - 1) +
                          " (one per frame after the first)");
    }
    odometry = std::move(given);
  }
  const std::optional<std::vector<Eigen::Isometry3d>> groundtruth = sequence.groundtruth;
  const FrontendOptions frontend_options =
      options_for_rig(options.frontend, options.up_axis, sequence.rig.T_cam0_body);
  StereoFrontend frontend(std::move(sequence), frontend_options, std::move(detections),
                          std::move(odometry));

  RobotRun run;
  run.camera = frontend.camera();
  run.data.index = robot;
  run.data.has_features = true;
  run.summary.sequence = folder.string();
  run.summary.frames = frames;
  run.summary.min_tracks = std::numeric_limits<int>::max();
  std::vector<double> total, total_cpu, processing_cpu, load, rectify, track, odometry_ms, objects,
      translation_sigmas, rotation_sigmas, row_sigmas;
  double track_sum = 0.0, length_sum = 0.0, circular = 0.0, epipolar = 0.0, ransac = 0.0,
         outliers = 0.0, reanchored = 0.0;
  LandmarkId largest_id = -1;
  std::vector<std::vector<std::array<float, 2>>> alignment_variances;
  while (!frontend.done()) {
    FrontendFrame frame = frontend.process_next();
    const int tracks = static_cast<int>(frame.input.features.size());
    track_sum += tracks;
    run.summary.min_tracks = std::min(run.summary.min_tracks, tracks);
    length_sum += frame.mean_track_length;
    circular += frame.counts.rejected_circular;
    epipolar += frame.counts.rejected_epipolar;
    ransac += frame.counts.rejected_ransac;
    reanchored += frame.counts.reanchored;
    for (const StereoObservation& feature : frame.input.features) {
      largest_id = std::max(largest_id, feature.id);
    }
    if (frame.row_noise_sigma > 0.0) row_sigmas.push_back(frame.row_noise_sigma);
    run.summary.detections += frame.detections;
    run.summary.objects_observed += frame.objects_observed;
    run.summary.objects_ambiguous += frame.objects_ambiguous;
    run.summary.objects_inconsistent += frame.objects_inconsistent;
    if (frame.input.frame > 0) {
      outliers += static_cast<double>(frame.motion.outliers.size());
      if (!frame.motion.valid) {
        ++run.summary.odometry_failures;
      } else {
        translation_sigmas.push_back(
            std::sqrt(frame.motion.covariance.diagonal().head<3>().mean()));
        rotation_sigmas.push_back(std::sqrt(frame.motion.covariance.diagonal().tail<3>().mean()));
      }
      run.data.odometry.push_back(*frame.input.T_previous_current);
      run.motions.push_back(frame.motion);
    }
    total.push_back(frame.timings.total);
    total_cpu.push_back(frame.timings.total_cpu);
    processing_cpu.push_back(frame.timings.processing_cpu);
    load.push_back(frame.timings.load);
    rectify.push_back(frame.timings.rectify);
    track.push_back(frame.timings.track);
    odometry_ms.push_back(frame.timings.odometry);
    objects.push_back(frame.timings.objects);
    run.data.objects.push_back(std::move(frame.input.objects));
    run.class_names.push_back(std::move(frame.object_class_names));
    run.data.features.push_back(std::move(frame.input.features));
    alignment_variances.push_back(std::move(frame.alignment_variances));
    if (options.progress) options.progress(robot, frame.input.frame, frames);
  }
  if (groundtruth) {
    run.data.groundtruth = *groundtruth;
  } else {
    // No ground truth: the known start is the identity and the poses are dead reckoning.
    run.data.groundtruth.push_back(Eigen::Isometry3d::Identity());
    for (const Eigen::Isometry3d& motion : run.data.odometry) {
      run.data.groundtruth.push_back(run.data.groundtruth.back() * motion);
    }
  }
  SequenceSummary& s = run.summary;
  s.tracks_per_frame = track_sum / frames;
  s.mean_track_length = length_sum / frames;
  s.distinct_tracks = largest_id + 1;
  s.rejected_circular_per_frame = circular / frames;
  s.rejected_epipolar_per_frame = epipolar / frames;
  s.rejected_ransac_per_frame = ransac / frames;
  s.reanchored_per_frame = reanchored / frames;
  s.odometry_outliers_per_frame = outliers / std::max(frames - 1, 1);
  s.odometry_translation_sigma = median_of(translation_sigmas);
  s.odometry_rotation_sigma = median_of(rotation_sigmas);
  s.feature_pixel_sigma = median_of(row_sigmas);
  s.feature_track_sigma = track_consistency(run.camera, run.data.odometry, run.data.features).sigma;
  if (options.observation_noise) {
    s.observation_noise = fit_observation_noise(run.data.features, alignment_variances,
                                                std::max(s.feature_track_sigma, kMinFeatureSigma));
    if (s.observation_noise.valid()) {
      for (std::size_t frame = 0; frame < run.data.features.size(); ++frame) {
        for (std::size_t n = 0; n < run.data.features[frame].size(); ++n) {
          const auto& variances = alignment_variances[frame][n];
          run.data.features[frame][n].sigma = s.observation_noise.sigma(variances[0], variances[1]);
        }
      }
    }
  }
  s.total_ms = percentiles_of(total);
  s.total_cpu_ms = percentiles_of(total_cpu);
  s.processing_cpu_ms = percentiles_of(processing_cpu);
  s.load_ms = percentiles_of(load);
  s.rectify_ms = percentiles_of(rectify);
  s.track_ms = percentiles_of(track);
  s.odometry_ms = percentiles_of(odometry_ms);
  s.objects_ms = percentiles_of(objects);
  return run;
}

/// The keys a detector model may set (FrontendRunOptions::detector_model): the object noise,
/// and the point-feature tracks' drift measured on the same calibration sequence.
const std::set<std::string>& detector_model_keys() {
  static const std::set<std::string> keys = {
      "feature_drift_sigma",      "object_noise",
      "object_noise_constant",    "object_noise_persistent",
      "object_noise_correlation", "object_offset_sigma",
      "object_offset_walk",       "object_displacement_sigma",
      "object_displacement_walk", "object_init_max_reprojection_error"};
  return keys;
}

/// The detector model file's text, read and checked: only detector_model_keys(), valid over the
/// defaults. Throws FrontendError.
std::string load_detector_model(const fs::path& file) {
  try {
    const std::string text = config::read_config_text(file, "detector model");
    const YAML::Node root = config::load_yaml(text, file.string());
    if (!root.IsMap() || root.size() == 0) {
      throw FrontendError(file.string() +
                          ": a detector model is a map of estimator object noise keys "
                          "(and feature_drift_sigma) "
                          "(concord calibrate --detector-model writes one)");
    }
    std::string refused;
    for (const auto& entry : root) {
      const std::string key = entry.first.as<std::string>();
      if (detector_model_keys().count(key) == 0) refused += (refused.empty() ? "" : ", ") + key;
    }
    if (!refused.empty()) {
      std::string allowed;
      for (const std::string& key : detector_model_keys()) allowed += " " + key;
      throw FrontendError(file.string() + ": not a detector's key: " + refused +
                          " (a detector model holds only" + allowed + ")");
    }
    (void)config::parse_estimator_options(text, file.string());
    return text;
  } catch (const config::ConfigError& error) {
    throw FrontendError(error.what());
  } catch (const YAML::Exception& error) {
    throw FrontendError(file.string() + ": " + error.what());
  }
}

}  // namespace

EstimatorOptions suggested_estimator_options(const FrontendRunSummary& summary,
                                             const StereoCamera& camera,
                                             const FrontendOptions& options) {
  std::vector<double> translation, rotation, feature;
  for (const SequenceSummary& robot : summary.robots) {
    if (robot.odometry_translation_sigma > 0.0)
      translation.push_back(robot.odometry_translation_sigma);
    if (robot.odometry_rotation_sigma > 0.0) rotation.push_back(robot.odometry_rotation_sigma);
    if (robot.feature_track_sigma > 0.0) feature.push_back(robot.feature_track_sigma);
  }
  EstimatorOptions estimator;
  // A floor keeps a perfectly static or texture-poor sequence from claiming zero noise.
  estimator.odometry_translation_sigma = std::max(median_of(translation), 1e-4);
  estimator.odometry_rotation_sigma = std::max(median_of(rotation), 1e-5);
  const double feature_sigma = std::max(median_of(feature), kMinFeatureSigma);
  estimator.feature_noise = StereoNoise::isotropic(feature_sigma);
  estimator.feature_max_reprojection_error = 0.0;  // no fixed bound: the chi-square gate decides
  // The tracker's KLT follows a feature frame to frame, so its error drifts along a track: the
  // estimator uses a track in chunks of at most this many observations (docs/frontend.md, "Track
  // drift"; chosen on a rendered team that is not the one the results report).
  estimator.feature_max_observations = 12;
  estimator.object_noise = StereoNoise::isotropic(options.objects.detection_sigma);
  estimator.object_init_max_reprojection_error = 3.0 * options.objects.detection_sigma;
  const double focal_baseline = camera.K(0, 0) * camera.baseline();
  estimator.feature_min_distance = 0.2;
  estimator.feature_max_distance = focal_baseline / 1.0;
  estimator.object_min_distance = 0.5;
  estimator.object_max_distance = focal_baseline / 5.0;
  estimator.object_archive_after_frames = 10;
  return estimator;
}

std::vector<fs::path> list_sequences(const fs::path& input) {
  if (!fs::is_directory(input)) throw FrontendError(input.string() + ": input folder not found");
  if (is_stereo_sequence(input)) return {input};
  std::vector<fs::path> sequences;
  for (int robot = 0;; ++robot) {
    const fs::path folder = input / dataset::robot_folder_name(robot);
    if (!fs::is_directory(folder)) break;
    sequences.push_back(folder);
  }
  if (sequences.empty()) {
    throw FrontendError(input.string() +
                        ": neither a stereo sequence (KITTI calib.txt, EuRoC mav0/) nor a folder "
                        "of robot_NN sequences");
  }
  return sequences;
}

FrontendRunSummary run_frontend(const fs::path& input, const fs::path& out,
                                const FrontendRunOptions& options) {
  const std::vector<std::string> problems = options.frontend.validate();
  if (!problems.empty()) {
    std::string message = "invalid front-end options:";
    for (const std::string& problem : problems) message += " " + problem + ";";
    throw FrontendError(message);
  }
  static const std::set<std::string> kAxes = {"unknown", "+x", "-x", "+y", "-y", "+z", "-z"};
  if (kAxes.count(options.up_axis) == 0) {
    throw FrontendError("up axis '" + options.up_axis +
                        "': expected unknown, +x, -x, +y, -y, +z or -z");
  }
  // The detector model is checked before any image is read.
  std::optional<std::string> detector_model;
  if (!options.detector_model.empty()) detector_model = load_detector_model(options.detector_model);
  const std::vector<fs::path> sequences = list_sequences(input);
  const bool single = sequences.size() == 1 && sequences.front() == input;
  if (!single && (!options.detections.empty() || !options.odometry.empty())) {
    throw FrontendError(input.string() +
                        ": --detections and --odometry apply to a single sequence; a team's "
                        "robot_NN folders hold their own detections.csv");
  }

  dataset::Dataset data;
  data.name = options.name;
  FrontendRunSummary summary;
  // How the output's ids and starts are to be read, unless given: as the team folder's
  // dataset.json declares them (a rendered team); else, for a team, private (a detector's track
  // ids are its own robot's) and unknown (each robot's ground truth, if any, may be in a frame
  // of its own). One robot: global and known (there is no one to associate with).
  if (!single && fs::exists(input / "dataset.json")) {
    const dataset::Conventions declared = dataset::read_conventions(input / "dataset.json");
    summary.object_ids = declared.object_ids;
    summary.start_poses = declared.start_poses;
  } else if (!single && sequences.size() > 1) {
    summary.object_ids = dataset::ObjectIds::kPrivate;
    summary.start_poses = dataset::StartPoses::kUnknown;
  }
  std::vector<std::vector<std::vector<std::string>>> runs;
  for (std::size_t robot = 0; robot < sequences.size(); ++robot) {
    RobotRun run = run_sequence(sequences[robot], static_cast<int>(robot), single, options);
    runs.push_back(std::move(run.class_names));
    if (robot == 0) {
      data.camera = run.camera;
    } else if (!same_camera(run.camera, data.camera)) {
      throw FrontendError(sequences[robot].string() +
                          ": its rectified camera differs from robot_00's; a dataset has one "
                          "camera, so every robot must share the calibration");
    }
    // The odometry's own covariance of every motion (failures included: their covariance is
    // the failure sigmas), written as odometry_covariance.csv and used by the estimator.
    run.data.odometry_covariance.clear();
    for (const MotionEstimate& motion : run.motions)
      run.data.odometry_covariance.emplace_back(motion.covariance);
    data.robots.push_back(std::move(run.data));
    summary.robots.push_back(std::move(run.summary));
  }

  data.object_ids = options.object_ids.value_or(summary.object_ids);
  data.start_poses = options.start_poses.value_or(summary.start_poses);
  summary.object_ids = data.object_ids;
  summary.start_poses = data.start_poses;
  summary.classes = number_classes(runs, options.classes, data.robots);

  dataset::write_dataset(data, out);
  if (!single && fs::exists(input / "objects_gt.csv")) {
    fs::copy_file(input / "objects_gt.csv", out / "objects_gt.csv",
                  fs::copy_options::overwrite_existing);
  }
  // A team whose object ids are private may carry their truth (evaluation only).
  for (std::size_t robot = 0; robot < sequences.size() && !single; ++robot) {
    const fs::path truth = sequences[robot] / "object_ids_truth.csv";
    if (data.object_ids == dataset::ObjectIds::kPrivate && fs::exists(truth)) {
      fs::copy_file(truth, out / dataset::robot_folder_name(static_cast<int>(robot)) / truth.filename(),
                    fs::copy_options::overwrite_existing);
    }
  }
  std::string estimator_yaml =
      "# Estimator options for this dataset, written by `concord frontend`: the noise values are\n"
      "# the front-end's own (odometry: median reported standard deviation; features: the tracks'\n"
      "# consistency" +
      (detector_model
           ? ", and any drift the detector model gives; objects: the detector model\n# " +
                 options.detector_model.string()
           : std::string("; objects: the detector's stated accuracy,\n# "
                         "objects.detection_sigma")) +
      "); the depth limits follow from fx * baseline. See docs/frontend.md.\n";
  EstimatorOptions estimator = suggested_estimator_options(summary, data.camera, options.frontend);
  if (detector_model) {
    try {  // the model's keys over the front-end's own values, validated together
      estimator = config::parse_estimator_options(*detector_model,
                                                  options.detector_model.string(), estimator);
    } catch (const config::ConfigError& error) {
      throw FrontendError(error.what());
    }
  }
  estimator_yaml += config::to_yaml(estimator);
  if (options.up_axis != "unknown") {
    estimator_yaml += "# The robots' up axis (concord frontend --up-axis; docs/association.md).\n"
                      "association:\n  start_up_axis: \"" + options.up_axis + "\"\n";
  }
  dataset::write_file_atomically(out / "estimator.yaml", estimator_yaml);

  nlohmann::ordered_json document;
  document["input"] = input.string();
  document["odometry"] =
      options.odometry.empty() ? "stereo visual odometry" : options.odometry.string();
  document["options"] =
      options_json(options_for_rig(options.frontend, options.up_axis, data.camera.T_cam0_body));
  document["detector_model"] = options.detector_model.string();
  document["object_ids"] = dataset::to_string(summary.object_ids);
  document["start_poses"] = dataset::to_string(summary.start_poses);
  document["classes"] = summary.classes;
  document["robots"] = nlohmann::ordered_json::array();
  for (const SequenceSummary& robot : summary.robots)
    document["robots"].push_back(summary_json(robot));
  dataset::write_file_atomically(out / "frontend.json", document.dump(2) + "\n");
  return summary;
}

}  // namespace concord::frontend
