#pragma once
/// \file
/// The multi-robot dataset simulator (the paper's §VI-B1): every robot flies a Lissajous figure
/// eight of its own orientation, phase and scale around the origin, so paths overlap and
/// robots see common objects; its odometry is the true relative motion perturbed on the right by
/// Gaussian noise; object landmarks (global ids) are placed in view of trajectory points; point
/// landmarks are spawned in each robot's view as it moves and retired when they leave it or the
/// tracker loses them (robot-private track ids); observations are stereo projections with Gaussian
/// noise in normalized image coordinates (K is the identity). The result is a dataset::Dataset in
/// the shared layout (name and sensor "sim", so `concord replay` uses configs/sensors/sim.yaml).
/// docs/simulator.md describes the model and every parameter.
///
/// Deterministic: the same options give the same dataset bit for bit (up to the platform's libm
/// in sin/cos/log). Every robot draws from its own std::mt19937_64 streams seeded from (seed,
/// robot index), and normal variates come from our own Box-Muller transform, so robot k's path,
/// odometry and point features do not depend on how many robots are simulated (its object
/// observations do: objects are placed around all robots' paths).

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "concord/dataset/dataset.h"
#include "concord/estimator/types.h"

namespace concord::sim {

/// Every parameter of a simulation, with defaults in-class (the CLI flag is in brackets).
struct SimulationOptions {
  // --- Team and scene ---
  /// Number of robots (--robots), 1 to 1000.
  int robots = 3;
  /// Frames per robot (--frames).
  int frames = 420;
  /// Object landmarks in the scene, global ids 0..objects-1 (--objects). May be 0.
  int objects = 210;
  /// Point features visible in every frame of every robot (--points-per-frame); 0 writes no
  /// features.csv.
  int points_per_frame = 10;
  /// Probability that the feature tracker loses a visible point at a frame (--point-track-loss),
  /// in [0, 1); its track ends there, like a track that leaves the view.
  double point_track_loss = 0.2;
  /// Seed of every random stream (--seed).
  std::uint64_t seed = 1;

  // --- Noise (one standard deviation) ---
  /// Odometry translation noise per axis per frame, metres (--odometry-translation-noise).
  double odometry_translation_noise = 0.015;
  /// Odometry rotation noise per axis per frame, radians (--odometry-rotation-noise).
  double odometry_rotation_noise = 0.01;
  /// Noise of every observed coordinate (u_left, v_left, u_right, v_right), normalized image
  /// units (--pixel-noise).
  double pixel_noise = 0.01;
  /// Noise of the object observations' coordinates alone, normalized image units
  /// (--object-noise): a detector's box centres are less precise than tracked corners. Unset:
  /// pixel_noise.
  std::optional<double> object_noise;
  /// The object observations' noise: object_noise, else pixel_noise.
  double object_pixel_noise() const { return object_noise.value_or(pixel_noise); }

  // --- Stereo camera (K = identity; body x right, y forward, z up; camera looks along body y) ---
  /// Distance of the right camera along the left camera's x axis, metres (--baseline).
  double baseline = 0.54;
  /// Full horizontal / vertical field of view of each camera, degrees (--horizontal-fov,
  /// --vertical-fov), in (0, 180).
  double horizontal_fov_degrees = 70.0;
  double vertical_fov_degrees = 70.0;
  /// A landmark is observed only with a left-camera depth in [min_depth, max_depth], metres
  /// (--min-depth, --max-depth).
  double min_depth = 0.5;
  double max_depth = 10.0;

  // --- Paths. Robot i follows p(theta) = centre_i + scale_i Rz(yaw_i) (amplitude_x
  //     sin(frequency_x theta), amplitude_y sin(frequency_y theta), amplitude_z cos(theta)),
  //     theta = 2 pi k / period_frames + phase_i (docs/simulator.md).
  /// Frames per lap of the Lissajous curve (--period).
  int period_frames = 420;
  /// Half-extent of the curve along its own x / y / z axes, metres (--amplitude-x, -y, -z).
  double amplitude_x = 10.0;
  double amplitude_y = 10.0;
  double amplitude_z = 1.0;
  /// Integer frequencies of the horizontal axes (--frequency-x, --frequency-y); 1 and 2 draw a
  /// figure eight. Divided by their greatest common divisor they must not both be odd (such a
  /// curve stops and turns back on itself).
  int frequency_x = 1;
  int frequency_y = 2;
  /// Distance of each curve's centre from the world origin, in the direction of its yaw, metres
  /// (--centre-offset). Robot i's yaw is 2 pi frac(i / golden ratio).
  double centre_offset = 5.0;
  /// Robot scales are uniform in [1 - scale_spread, 1 + scale_spread] (--scale-spread), in
  /// [0, 1).
  double scale_spread = 0.2;

  // --- Objects ---
  /// Object j is placed in view of a random frame of robot j mod robots, at a left-camera depth
  /// uniform in [object_min_depth, object_max_depth] metres (--object-min-depth,
  /// --object-max-depth), inside [min_depth, max_depth].
  double object_min_depth = 2.0;
  double object_max_depth = 8.0;
  /// Detector classes (--classes): each object gets a class uniform in [0, classes), written in
  /// objects.csv's class column; 0 writes no class column.
  int classes = 0;
  /// Fraction of object detections that are false (--false-detections), in [0, 0.5]: each robot
  /// hallucinates phantom objects of its own (a static point in view, a random class, tracked for
  /// 3 to 10 frames while visible, ids that have no ground truth), as many as make this fraction of
  /// its detections on average.
  double false_detection_rate = 0.0;

  // --- Variants (dataset::make_variant) ---
  /// Private object ids (--private-ids): each robot numbers its objects its own way;
  /// robot_XX/object_ids_truth.csv maps them to objects_gt.csv (false detections to -1).
  bool private_ids = false;
  /// Unknown start poses (--unknown-start): each robot's filter starts at the identity of its own
  /// frame; ground truth stays in the world frame.
  bool unknown_start = false;

  /// Every problem with the values, each naming the flag and the bad value; empty when valid.
  std::vector<std::string> validate() const;
};

/// The simulated stereo rig: K = identity, T_cam_body maps body (x right, y forward, z up) to the
/// optical frame (x right, y down, z forward), the right camera at +baseline along x.
StereoCamera make_camera(const SimulationOptions& options);

/// First id of robot r's phantom objects (false detections) with global ids:
/// kPhantomIdBase * (r + 1); they have no ground truth.
inline constexpr LandmarkId kPhantomIdBase = 1'000'000'000;

/// Simulates the team. Throws std::invalid_argument listing every problem if the options are
/// invalid, or if no object can be placed where both cameras see it (a baseline too wide for the
/// fields of view and depth range).
dataset::Dataset simulate(const SimulationOptions& options);

/// Where the ray origin + d * direction first meets a surface of a world: d (> 0), or nothing.
using SurfaceCast = std::function<std::optional<double>(const Eigen::Vector3d& origin,
                                                        const Eigen::Vector3d& direction)>;

/// Replaces every robot's point features (`simulate` places their points in the free volume in
/// view) by tracks of points on the surfaces of a world (`concord sim --render`), so the
/// simulator's exact tracks are of the same scene as the rendered images: a new point is where
/// the ray through a uniformly drawn left-image position first meets a surface, at any depth
/// beyond min_depth (a corner detector on a grid finds them on far walls as on near boxes); a
/// track continues while both cameras see its point unoccluded, in their fields of view, and the
/// tracker does not lose it (point_track_loss). Noise and ids as `simulate`'s; deterministic.
void place_point_features_on_surfaces(dataset::Dataset& data, const SimulationOptions& options,
                                      const SurfaceCast& cast);

/// Counts of a dataset, for the CLI's summary line and the tests.
struct SimulationSummary {
  int robots = 0;
  long long frames = 0;  ///< summed over robots
  int objects = 0;       ///< ground-truth objects
  long long object_observations = 0;
  long long feature_observations = 0;
  long long feature_tracks = 0;  ///< distinct (robot, track id) pairs
  /// object_observations / frames, feature_observations / frames, feature_observations / tracks.
  double objects_per_frame = 0.0;
  double features_per_frame = 0.0;
  double mean_track_length = 0.0;
};

SimulationSummary summarize(const dataset::Dataset& dataset);

/// The options as one JSON object (keys are the field names), written next to a simulated
/// dataset (simulation.json) so a reader sees what ran.
std::string to_json(const SimulationOptions& options);

}  // namespace concord::sim
