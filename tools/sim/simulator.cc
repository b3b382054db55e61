#include "sim/simulator.h"

#include <algorithm>
#include <atomic>
#include <charconv>
#include <cmath>
#include <limits>
#include <nlohmann/json.hpp>
#include <numbers>
#include <numeric>
#include <optional>
#include <random>
#include <stdexcept>
#include <string_view>
#include <thread>
#include <utility>

#include "concord/estimator/lie.h"
#include "sim/sim_math.h"

namespace concord::sim {

namespace {

// ------------------------------------------------------------------------------------------------
// Validation

std::string to_text(double value) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  return std::string(buffer, result.ptr);
}

std::string to_text(int value) { return std::to_string(value); }

/// Collects "--<flag> = <value>: must be <rule>" messages.
class Problems {
 public:
  template <typename Value>
  void add(std::string_view flag, Value value, std::string_view rule) {
    messages_.push_back("--" + std::string(flag) + " = " + to_text(value) + ": must be " +
                        std::string(rule));
  }
  void check_int(std::string_view flag, int value, int minimum, int maximum) {
    if (value < minimum || value > maximum) {
      add(flag, value, "in [" + std::to_string(minimum) + ", " + std::to_string(maximum) + "]");
    }
  }
  void check_positive(std::string_view flag, double value) {
    if (!(std::isfinite(value) && value > 0.0)) add(flag, value, "finite and > 0");
  }
  void check_non_negative(std::string_view flag, double value) {
    if (!(std::isfinite(value) && value >= 0.0)) add(flag, value, "finite and >= 0");
  }
  std::vector<std::string> take() { return std::move(messages_); }

 private:
  std::vector<std::string> messages_;
};

// ------------------------------------------------------------------------------------------------
// Portable random numbers: std::mt19937_64's output is fixed by the standard, the distributions
// are not, so uniform and normal variates are computed here.

/// Independent streams of one robot (or of the scene), so that e.g. the number of point features
/// does not change the odometry noise.
enum class Stream : std::uint64_t {
  kPath = 1,
  kOdometry,
  kPoints,
  kObjectNoise,
  kObjectPlacement,
  kObjectClass,
  kFalseDetections
};

/// The scene's own streams use this in place of a robot index.
constexpr std::uint64_t kSceneIndex = 0xffffffffULL;

class Random {
 public:
  Random(std::uint64_t seed, std::uint64_t index, Stream stream)
      : engine_(splitmix64(splitmix64(splitmix64(seed) ^ index) ^
                           static_cast<std::uint64_t>(stream))) {}

  /// Uniform in [0, 1), 53 random bits.
  double uniform() { return static_cast<double>(engine_() >> 11) * 0x1.0p-53; }
  double uniform(double low, double high) { return low + (high - low) * uniform(); }
  /// Uniform integer in [0, count).
  int uniform_index(int count) {
    return std::min(count - 1, static_cast<int>(uniform() * static_cast<double>(count)));
  }
  /// Standard normal by the Box-Muller transform (the second variate is kept for the next call).
  double normal() {
    if (spare_) return *std::exchange(spare_, std::nullopt);
    const double radius = std::sqrt(-2.0 * std::log(1.0 - uniform()));  // 1 - u in (0, 1]
    const double angle = 2.0 * std::numbers::pi * uniform();
    spare_ = radius * std::sin(angle);
    return radius * std::cos(angle);
  }

 private:
  std::mt19937_64 engine_;
  std::optional<double> spare_;
};

// ------------------------------------------------------------------------------------------------
// Paths

/// One robot's Lissajous curve.
struct Path {
  double yaw = 0.0;
  double phase = 0.0;
  double scale = 1.0;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
};

Path make_path(const SimulationOptions& options, int robot) {
  Random random(options.seed, static_cast<std::uint64_t>(robot), Stream::kPath);
  Path path;
  // Golden-ratio yaws spread the curves evenly for any team size, robot 0 keeps yaw 0.
  const double golden_fraction = std::numbers::phi - 1.0;
  double whole;
  path.yaw = 2.0 * std::numbers::pi * std::modf(robot * golden_fraction, &whole);
  path.phase = 2.0 * std::numbers::pi * random.uniform();
  path.scale = 1.0 + options.scale_spread * random.uniform(-1.0, 1.0);
  path.centre = yaw_rotation(path.yaw) * Eigen::Vector3d(options.centre_offset, 0.0, 0.0);
  return path;
}

/// T_world_body at frame k: on the curve, body y along the tangent, body x horizontal to the
/// right, body z up.
Eigen::Isometry3d pose_at(const SimulationOptions& options, const Path& path, int frame) {
  const double theta = 2.0 * std::numbers::pi * frame / options.period_frames + path.phase;
  const double a = options.frequency_x, b = options.frequency_y;
  const Eigen::Matrix3d R_world_curve = yaw_rotation(path.yaw);
  const Eigen::Vector3d p_curve(options.amplitude_x * std::sin(a * theta),
                                options.amplitude_y * std::sin(b * theta),
                                options.amplitude_z * std::cos(theta));
  const Eigen::Vector3d tangent_curve(options.amplitude_x * a * std::cos(a * theta),
                                      options.amplitude_y * b * std::cos(b * theta),
                                      -options.amplitude_z * std::sin(theta));
  // validate() keeps the horizontal tangent away from zero, so forward x up is well defined.
  const Eigen::Vector3d forward = (R_world_curve * tangent_curve).normalized();
  const Eigen::Vector3d right = forward.cross(Eigen::Vector3d::UnitZ()).normalized();
  const Eigen::Vector3d up = right.cross(forward);
  Eigen::Isometry3d T_world_body = Eigen::Isometry3d::Identity();
  T_world_body.linear().col(0) = right;
  T_world_body.linear().col(1) = forward;
  T_world_body.linear().col(2) = up;
  T_world_body.translation() = path.centre + path.scale * (R_world_curve * p_curve);
  return T_world_body;
}

// ------------------------------------------------------------------------------------------------
// Observations

/// The camera's visibility rules and projection.
class Viewer {
 public:
  Viewer(const SimulationOptions& options, const StereoCamera& camera)
      : camera_(camera),
        tan_half_horizontal_(
            std::tan(0.5 * options.horizontal_fov_degrees * std::numbers::pi / 180.0)),
        tan_half_vertical_(std::tan(0.5 * options.vertical_fov_degrees * std::numbers::pi / 180.0)),
        min_depth_(options.min_depth),
        max_depth_(options.max_depth) {}

  /// Sets the pose the next calls look from.
  void look_from(const Eigen::Isometry3d& T_world_body) {
    const Eigen::Isometry3d T_body_world = T_world_body.inverse();
    T_cam0_world_ = camera_.T_cam0_body * T_body_world;
    T_cam1_world_ = camera_.T_cam1_body() * T_body_world;
    T_world_cam0_ = T_world_body * camera_.T_cam0_body.inverse();
  }

  /// Noiseless normalized (x_left, y_left, x_right, y_right) of a world point, or nothing unless
  /// it is in front of both cameras, inside both fields of view and at a left depth in
  /// [min_depth, max_depth].
  std::optional<Eigen::Vector4d> project(const Eigen::Vector3d& p_world) const {
    return project_camera(T_cam0_world_ * p_world, T_cam1_world_ * p_world);
  }

  std::optional<Eigen::Vector4d> project_camera(const Eigen::Vector3d& p_cam0,
                                                const Eigen::Vector3d& p_cam1) const {
    if (!(p_cam0.z() >= min_depth_ && p_cam0.z() <= max_depth_ && p_cam1.z() > 0.0)) {
      return std::nullopt;
    }
    const Eigen::Vector4d xy(p_cam0.x() / p_cam0.z(), p_cam0.y() / p_cam0.z(),
                             p_cam1.x() / p_cam1.z(), p_cam1.y() / p_cam1.z());
    if (std::abs(xy(0)) > tan_half_horizontal_ || std::abs(xy(2)) > tan_half_horizontal_ ||
        std::abs(xy(1)) > tan_half_vertical_ || std::abs(xy(3)) > tan_half_vertical_) {
      return std::nullopt;
    }
    return xy;
  }

  /// A ray (x, y, 1) in the left camera's frame through a uniformly drawn position of the
  /// central `fov_fraction` of its field of view (x drawn first, then y).
  Eigen::Vector3d random_ray(Random& random, double fov_fraction) const {
    const double x = fov_fraction * random.uniform(-tan_half_horizontal_, tan_half_horizontal_);
    const double y = fov_fraction * random.uniform(-tan_half_vertical_, tan_half_vertical_);
    return {x, y, 1.0};
  }

  /// A random point in the left camera's view at a depth in [depth_low, depth_high] that both
  /// cameras see, in world coordinates, or nothing after `attempts` failed draws.
  std::optional<Eigen::Vector3d> sample_in_view(Random& random, double depth_low, double depth_high,
                                                double fov_fraction, int attempts) const {
    const Eigen::Isometry3d T_cam1_cam0 = camera_.T_cam0_cam1.inverse();
    for (int attempt = 0; attempt < attempts; ++attempt) {
      const Eigen::Vector3d ray = random_ray(random, fov_fraction);
      // Depth with density proportional to depth^2: points spread uniformly in the volume of
      // the view, as a static world of uniform density looks through a camera.
      const double cube_low = depth_low * depth_low * depth_low;
      const double depth =
          std::cbrt(random.uniform(cube_low, depth_high * depth_high * depth_high));
      const Eigen::Vector3d p_cam0 = depth * ray;
      if (project_camera(p_cam0, T_cam1_cam0 * p_cam0)) return T_world_cam0_ * p_cam0;
    }
    return std::nullopt;
  }

 private:
  StereoCamera camera_;
  double tan_half_horizontal_, tan_half_vertical_, min_depth_, max_depth_;
  Eigen::Isometry3d T_cam0_world_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_cam1_world_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_world_cam0_ = Eigen::Isometry3d::Identity();
};

/// Image coordinates (K = identity) with Gaussian noise on each of the four.
Eigen::Vector4d noisy(const Eigen::Vector4d& xy, double sigma, Random& random) {
  Eigen::Vector4d uv = xy;
  if (sigma > 0.0) {
    for (int i = 0; i < 4; ++i) uv(i) += sigma * random.normal();
  }
  return uv;
}

/// Most threads simulate() uses (robots are simulated in parallel).
constexpr int kMaxThreads = 8;

/// Draws attempted per missing point feature before a frame is left with fewer.
constexpr int kSpawnAttempts = 100;

/// A point landmark while some robot's tracker follows it.
struct ActivePoint {
  LandmarkId id;
  Eigen::Vector3d p_world;
};

/// Continues a frame's point tracks: a track ends for good when the tracker loses it
/// (point_track_loss) or `project` no longer sees its point; the others are observed with noise.
template <typename Project>
void continue_point_tracks(const SimulationOptions& options, const Project& project,
                           Random& random, std::vector<ActivePoint>& active,
                           std::vector<ActivePoint>& still_visible,
                           std::vector<StereoObservation>& features) {
  still_visible.clear();
  for (const ActivePoint& point : active) {
    const bool lost = options.point_track_loss > 0.0 && random.uniform() < options.point_track_loss;
    if (lost) continue;
    if (const auto xy = project(point.p_world)) {
      features.push_back({point.id, noisy(*xy, options.pixel_noise, random)});
      still_visible.push_back(point);
    }
  }
  std::swap(active, still_visible);
}

/// A phantom object (false detection) while the robot hallucinates it.
struct Phantom {
  LandmarkId id;
  Eigen::Vector3d p_world;
  int object_class;
  int frames_left;
};

/// Odometry, object and point-feature observations of one robot along its ground truth.
void observe(const SimulationOptions& options, const StereoCamera& camera,
             const std::vector<Eigen::Vector3d>& object_positions,
             const std::vector<int>& object_classes, dataset::RobotData& robot) {
  const int frames = robot.num_frames();
  const auto index = static_cast<std::uint64_t>(robot.index);

  // 1. Odometry: the true T_body(k-1)_body(k) perturbed on the right, T exp(xi^), xi = [rho; phi].
  Random odometry_random(options.seed, index, Stream::kOdometry);
  robot.odometry.reserve(frames - 1);
  for (int k = 1; k < frames; ++k) {
    const Eigen::Isometry3d relative = robot.groundtruth[k - 1].inverse() * robot.groundtruth[k];
    lie::Vector6d xi;
    for (int i = 0; i < 6; ++i) {
      const double sigma =
          i < 3 ? options.odometry_translation_noise : options.odometry_rotation_noise;
      xi(i) = sigma * odometry_random.normal();
    }
    robot.odometry.push_back(lie::orthonormalized(relative * lie::se3_exp(xi)));
  }

  Viewer viewer(options, camera);
  Random object_noise(options.seed, index, Stream::kObjectNoise);
  Random point_random(options.seed, index, Stream::kPoints);
  robot.objects.assign(frames, {});
  robot.object_classes.assign(frames, {});
  robot.has_object_classes = options.classes > 0;
  robot.features.assign(frames, {});
  robot.has_features = options.points_per_frame > 0;
  Random false_random(options.seed, index, Stream::kFalseDetections);
  std::vector<Phantom> phantoms, phantoms_kept;
  LandmarkId next_phantom_id = kPhantomIdBase * (robot.index + 1);
  // Phantoms last 3 to 10 frames (6.5 on average, fewer when they leave the view).
  constexpr int kPhantomMinFrames = 3;
  constexpr int kPhantomMaxFrames = 10;
  const double phantoms_per_true_detection = options.false_detection_rate /
                                             (1.0 - options.false_detection_rate) /
                                             (0.5 * (kPhantomMinFrames + kPhantomMaxFrames));
  std::vector<ActivePoint> active, still_visible;
  LandmarkId next_track_id = 0;
  for (int k = 0; k < frames; ++k) {
    viewer.look_from(robot.groundtruth[k]);

    // 2. Objects: every object in view.
    for (std::size_t id = 0; id < object_positions.size(); ++id) {
      if (const auto xy = viewer.project(object_positions[id])) {
        robot.objects[k].push_back(
            {static_cast<LandmarkId>(id), noisy(*xy, options.object_pixel_noise(), object_noise)});
        if (robot.has_object_classes) robot.object_classes[k].push_back(object_classes[id]);
      }
    }
    // 2b. False detections: phantoms continue while in view and alive; new ones are spawned in
    //     proportion to the true detections of the frame.
    if (options.false_detection_rate > 0.0) {
      const double expected = phantoms_per_true_detection * robot.objects[k].size();
      int spawn = static_cast<int>(expected);
      if (false_random.uniform() < expected - spawn) ++spawn;
      for (int n = 0; n < spawn; ++n) {
        const auto p_world = viewer.sample_in_view(false_random, options.object_min_depth,
                                                   options.object_max_depth, 0.9, kSpawnAttempts);
        if (!p_world) break;
        const int object_class =
            options.classes > 0 ? false_random.uniform_index(options.classes) : 0;
        const int length = kPhantomMinFrames +
                           false_random.uniform_index(kPhantomMaxFrames - kPhantomMinFrames + 1);
        phantoms.push_back({next_phantom_id++, *p_world, object_class, length});
      }
      phantoms_kept.clear();
      for (Phantom& phantom : phantoms) {
        const auto xy = viewer.project(phantom.p_world);
        if (!xy) continue;
        robot.objects[k].push_back(
            {phantom.id, noisy(*xy, options.object_pixel_noise(), false_random)});
        if (robot.has_object_classes) robot.object_classes[k].push_back(phantom.object_class);
        if (--phantom.frames_left > 0) phantoms_kept.push_back(phantom);
      }
      std::swap(phantoms, phantoms_kept);
    }

    if (!robot.has_features) continue;
    // 3. Point features: tracks continue while their point stays in view and end for good when
    //    it leaves; new points are spawned in view up to points_per_frame. The work per frame is
    //    proportional to the visible points.
    auto& features = robot.features[k];
    continue_point_tracks(
        options, [&viewer](const Eigen::Vector3d& p_world) { return viewer.project(p_world); },
        point_random, active, still_visible, features);
    for (int missing = options.points_per_frame - static_cast<int>(active.size()); missing > 0;
         --missing) {
      const auto p_world = viewer.sample_in_view(point_random, options.min_depth, options.max_depth,
                                                 1.0, kSpawnAttempts);
      if (!p_world) break;
      const auto xy = viewer.project(*p_world);
      if (!xy) continue;  // on the edge of the view after the round trip through world
      active.push_back({next_track_id++, *p_world});
      features.push_back({active.back().id, noisy(*xy, options.pixel_noise, point_random)});
    }
  }
}

}  // namespace

// ------------------------------------------------------------------------------------------------

std::vector<std::string> SimulationOptions::validate() const {
  Problems problems;
  problems.check_int("robots", robots, 1, 1000);
  problems.check_int("frames", frames, 1, 10'000'000);
  problems.check_int("objects", objects, 0, 10'000'000);
  problems.check_int("points-per-frame", points_per_frame, 0, 100'000);
  problems.check_non_negative("odometry-translation-noise", odometry_translation_noise);
  problems.check_non_negative("odometry-rotation-noise", odometry_rotation_noise);
  problems.check_non_negative("pixel-noise", pixel_noise);
  if (object_noise) problems.check_non_negative("object-noise", *object_noise);
  problems.check_int("classes", classes, 0, 1'000'000);
  if (!(false_detection_rate >= 0.0 && false_detection_rate <= 0.5)) {
    problems.add("false-detections", false_detection_rate, "in [0, 0.5]");
  }
  if (!(point_track_loss >= 0.0 && point_track_loss < 1.0)) {
    problems.add("point-track-loss", point_track_loss, "in [0, 1)");
  }
  problems.check_positive("baseline", baseline);
  if (!(horizontal_fov_degrees > 0.0 && horizontal_fov_degrees < 180.0)) {
    problems.add("horizontal-fov", horizontal_fov_degrees, "in (0, 180) degrees");
  }
  if (!(vertical_fov_degrees > 0.0 && vertical_fov_degrees < 180.0)) {
    problems.add("vertical-fov", vertical_fov_degrees, "in (0, 180) degrees");
  }
  problems.check_positive("min-depth", min_depth);
  problems.check_positive("max-depth", max_depth);
  if (std::isfinite(min_depth) && std::isfinite(max_depth) && !(max_depth > min_depth)) {
    problems.add("max-depth", max_depth, "greater than --min-depth = " + to_text(min_depth));
  }
  problems.check_int("period", period_frames, 2, 100'000'000);
  problems.check_positive("amplitude-x", amplitude_x);
  problems.check_positive("amplitude-y", amplitude_y);
  problems.check_non_negative("amplitude-z", amplitude_z);
  problems.check_int("frequency-x", frequency_x, 1, 1000);
  problems.check_int("frequency-y", frequency_y, 1, 1000);
  if (frequency_x >= 1 && frequency_y >= 1) {
    const int divisor = std::gcd(frequency_x, frequency_y);
    if ((frequency_x / divisor) % 2 == 1 && (frequency_y / divisor) % 2 == 1) {
      problems.add("frequency-y", frequency_y,
                   "such that frequency-x / gcd and frequency-y / gcd are not both odd (with "
                   "--frequency-x = " +
                       std::to_string(frequency_x) + " the path would stop and turn back)");
    }
  }
  problems.check_non_negative("centre-offset", centre_offset);
  if (!(scale_spread >= 0.0 && scale_spread < 1.0)) {
    problems.add("scale-spread", scale_spread, "in [0, 1)");
  }
  problems.check_positive("object-min-depth", object_min_depth);
  problems.check_positive("object-max-depth", object_max_depth);
  if (std::isfinite(object_min_depth) && std::isfinite(object_max_depth)) {
    if (!(object_max_depth >= object_min_depth)) {
      problems.add("object-max-depth", object_max_depth,
                   ">= --object-min-depth = " + to_text(object_min_depth));
    }
    if (object_min_depth < min_depth) {
      problems.add("object-min-depth", object_min_depth,
                   ">= --min-depth = " + to_text(min_depth) + " (objects must be observable)");
    }
    if (object_max_depth > max_depth) {
      problems.add("object-max-depth", object_max_depth,
                   "<= --max-depth = " + to_text(max_depth) + " (objects must be observable)");
    }
  }
  return problems.take();
}

StereoCamera make_camera(const SimulationOptions& options) {
  StereoCamera camera;
  camera.K.setIdentity();
  // Optical x = body x (right), optical y = -body z (down), optical z = body y (forward).
  camera.T_cam0_body.linear() << 1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0;
  camera.T_cam0_cam1.translation() = Eigen::Vector3d(options.baseline, 0.0, 0.0);
  return camera;
}

void place_point_features_on_surfaces(dataset::Dataset& data, const SimulationOptions& options,
                                      const SurfaceCast& cast) {
  if (options.points_per_frame <= 0) return;
  // Surfaces are seen at any depth beyond min_depth (not only to max_depth, the simulated
  // detectors' range).
  SimulationOptions any_depth = options;
  any_depth.max_depth = std::numeric_limits<double>::infinity();
  // A point on a surface is seen from a camera centre when the ray to it meets nothing first.
  const auto unoccluded = [&cast](const Eigen::Vector3d& centre, const Eigen::Vector3d& point) {
    const auto distance = cast(centre, point - centre);
    return !distance || *distance >= 1.0 - 1e-6;
  };
  for (dataset::RobotData& robot : data.robots) {
    Viewer viewer(any_depth, data.camera);
    Random point_random(options.seed, static_cast<std::uint64_t>(robot.index), Stream::kPoints);
    const auto frames = robot.num_frames();
    robot.features.assign(frames, {});
    robot.has_features = true;
    std::vector<ActivePoint> active, still_visible;
    LandmarkId next_track_id = 0;
    for (int k = 0; k < frames; ++k) {
      viewer.look_from(robot.groundtruth[k]);
      const Eigen::Isometry3d T_world_cam0 =
          robot.groundtruth[k] * data.camera.T_cam0_body.inverse();
      const Eigen::Isometry3d T_world_cam1 =
          robot.groundtruth[k] * data.camera.T_cam1_body().inverse();
      const Eigen::Vector3d left = T_world_cam0.translation(), right = T_world_cam1.translation();
      const auto seen = [&](const Eigen::Vector3d& p_world) -> std::optional<Eigen::Vector4d> {
        auto xy = viewer.project(p_world);
        if (xy && unoccluded(left, p_world) && unoccluded(right, p_world)) return xy;
        return std::nullopt;
      };
      auto& features = robot.features[k];
      continue_point_tracks(options, seen, point_random, active, still_visible, features);
      for (int missing = options.points_per_frame - static_cast<int>(active.size()), attempts = 0;
           missing > 0 && attempts < kSpawnAttempts * options.points_per_frame; ++attempts) {
        const Eigen::Vector3d direction =
            T_world_cam0.linear() * viewer.random_ray(point_random, 1.0);
        const auto distance = cast(left, direction);
        if (!distance) continue;
        const Eigen::Vector3d p_world = left + *distance * direction;
        const auto xy = seen(p_world);
        if (!xy) continue;
        active.push_back({next_track_id++, p_world});
        features.push_back({active.back().id, noisy(*xy, options.pixel_noise, point_random)});
        --missing;
      }
    }
  }
}

dataset::Dataset simulate(const SimulationOptions& options) {
  if (const auto problems = options.validate(); !problems.empty()) {
    std::string message = "invalid simulation options:";
    for (const auto& problem : problems) message += "\n  " + problem;
    throw std::invalid_argument(message);
  }
  dataset::Dataset data;
  data.name = "sim";
  data.sensor = "sim";
  data.camera = make_camera(options);

  // 1. Ground truth: every robot on its own curve.
  data.robots.resize(options.robots);
  for (int robot = 0; robot < options.robots; ++robot) {
    dataset::RobotData& robot_data = data.robots[robot];
    robot_data.index = robot;
    const Path path = make_path(options, robot);
    robot_data.groundtruth.reserve(options.frames);
    for (int k = 0; k < options.frames; ++k) {
      robot_data.groundtruth.push_back(pose_at(options, path, k));
    }
  }

  // 2. Objects: object j in view of a random frame of robot j mod robots.
  Random placement(options.seed, kSceneIndex, Stream::kObjectPlacement);
  Viewer viewer(options, data.camera);
  std::vector<Eigen::Vector3d> object_positions;
  object_positions.reserve(options.objects);
  for (int id = 0; id < options.objects; ++id) {
    const auto& robot = data.robots[id % options.robots];
    viewer.look_from(robot.groundtruth[placement.uniform_index(options.frames)]);
    // Within 90 % of the field of view, so the object stays in view for a few frames.
    auto p_world = viewer.sample_in_view(placement, options.object_min_depth,
                                         options.object_max_depth, 0.9, kSpawnAttempts);
    if (!p_world) {
      throw std::invalid_argument(
          "simulate: cannot place objects in view of both cameras; reduce --baseline or widen "
          "the fields of view");
    }
    object_positions.push_back(*p_world);
    data.objects_groundtruth[id] = *p_world;
  }
  // Classes from a stream of their own, so that --classes changes nothing else.
  std::vector<int> object_classes(options.objects, 0);
  if (options.classes > 0) {
    Random class_random(options.seed, kSceneIndex, Stream::kObjectClass);
    for (int& object_class : object_classes)
      object_class = class_random.uniform_index(options.classes);
  }

  // 3. Odometry and observations, robot by robot: the robots draw from their own streams, so
  //    they are simulated in parallel with the same result.
  std::atomic<int> next_robot{0};
  const auto work = [&] {
    for (int robot; (robot = next_robot++) < options.robots;) {
      observe(options, data.camera, object_positions, object_classes, data.robots[robot]);
    }
  };
  const int threads = std::clamp(static_cast<int>(std::thread::hardware_concurrency()), 1,
                                 std::min(options.robots, kMaxThreads));
  std::vector<std::jthread> helpers;
  for (int thread = 1; thread < threads; ++thread) helpers.emplace_back(work);
  work();
  helpers.clear();  // joins
  if (options.private_ids || options.unknown_start) {
    return dataset::make_variant(data, options.private_ids, options.unknown_start);
  }
  return data;
}

SimulationSummary summarize(const dataset::Dataset& dataset) {
  SimulationSummary summary;
  summary.robots = static_cast<int>(dataset.robots.size());
  summary.objects = static_cast<int>(dataset.objects_groundtruth.size());
  std::vector<LandmarkId> tracks;
  for (const auto& robot : dataset.robots) {
    summary.frames += robot.num_frames();
    for (const auto& frame : robot.objects) summary.object_observations += frame.size();
    tracks.clear();
    for (const auto& frame : robot.features) {
      summary.feature_observations += frame.size();
      for (const auto& observation : frame) tracks.push_back(observation.id);
    }
    std::sort(tracks.begin(), tracks.end());
    summary.feature_tracks += std::unique(tracks.begin(), tracks.end()) - tracks.begin();
  }
  const auto ratio = [](long long a, long long b) {
    return b > 0 ? static_cast<double>(a) / static_cast<double>(b) : 0.0;
  };
  summary.objects_per_frame = ratio(summary.object_observations, summary.frames);
  summary.features_per_frame = ratio(summary.feature_observations, summary.frames);
  summary.mean_track_length = ratio(summary.feature_observations, summary.feature_tracks);
  return summary;
}

std::string to_json(const SimulationOptions& options) {
  nlohmann::ordered_json json;
  json["robots"] = options.robots;
  json["frames"] = options.frames;
  json["objects"] = options.objects;
  json["points_per_frame"] = options.points_per_frame;
  json["seed"] = options.seed;
  json["odometry_translation_noise"] = options.odometry_translation_noise;
  json["odometry_rotation_noise"] = options.odometry_rotation_noise;
  json["pixel_noise"] = options.pixel_noise;
  json["object_noise"] = options.object_pixel_noise();
  json["point_track_loss"] = options.point_track_loss;
  json["baseline"] = options.baseline;
  json["horizontal_fov_degrees"] = options.horizontal_fov_degrees;
  json["vertical_fov_degrees"] = options.vertical_fov_degrees;
  json["min_depth"] = options.min_depth;
  json["max_depth"] = options.max_depth;
  json["period_frames"] = options.period_frames;
  json["amplitude_x"] = options.amplitude_x;
  json["amplitude_y"] = options.amplitude_y;
  json["amplitude_z"] = options.amplitude_z;
  json["frequency_x"] = options.frequency_x;
  json["frequency_y"] = options.frequency_y;
  json["centre_offset"] = options.centre_offset;
  json["scale_spread"] = options.scale_spread;
  json["object_min_depth"] = options.object_min_depth;
  json["object_max_depth"] = options.object_max_depth;
  json["classes"] = options.classes;
  json["false_detection_rate"] = options.false_detection_rate;
  json["private_ids"] = options.private_ids;
  json["unknown_start"] = options.unknown_start;
  return json.dump(2) + "\n";
}

}  // namespace concord::sim
