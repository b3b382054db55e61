#include "concord/estimator/options.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace concord {

namespace {

/// Shortest text that reads back as exactly `value`.
std::string to_text(double value) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  return std::string(buffer, result.ptr);
}

std::string to_text(int value) { return std::to_string(value); }

std::string to_text(const std::string& value) { return "\"" + value + "\""; }

std::string to_text(const std::array<double, 3>& value) {
  return "[" + to_text(value[0]) + ", " + to_text(value[1]) + ", " + to_text(value[2]) + "]";
}

/// Collects "<key> = <value>: must be <rule>" messages.
class Problems {
 public:
  template <typename Value>
  void add(std::string_view key, Value value, std::string_view rule) {
    messages_.push_back(std::string(key) + " = " + to_text(value) + ": must be " +
                        std::string(rule));
  }

  /// A standard deviation or a threshold: finite and > 0.
  void check_positive(std::string_view key, double value) {
    if (!(std::isfinite(value) && value > 0.0)) add(key, value, "finite and > 0");
  }

  /// An optional bound: finite and >= 0, 0 disables.
  void check_optional_bound(std::string_view key, double value) {
    if (!(std::isfinite(value) && value >= 0.0)) add(key, value, "finite and >= 0 (0 disables)");
  }

  /// A chi-square gate probability: in [0, 1), 0 disables.
  void check_probability(std::string_view key, double value) {
    if (!(value >= 0.0 && value < 1.0)) add(key, value, "in [0, 1) (0 disables)");
  }

  void check_stereo_noise(std::string_view key, const StereoNoise& noise) {
    const std::string prefix(key);
    check_positive(prefix + ".horizontal", noise.horizontal);
    check_positive(prefix + ".vertical", noise.vertical);
    check_positive(prefix + ".disparity", noise.disparity);
    check_positive(prefix + ".vertical_disparity", noise.vertical_disparity);
  }

  void check_at_least(std::string_view key, int value, int minimum) {
    if (value < minimum) add(key, value, ">= " + std::to_string(minimum));
  }

  /// An accepted depth interval: 0 < minimum < maximum, both finite.
  void check_distance_range(std::string_view minimum_key, double minimum,
                            std::string_view maximum_key, double maximum) {
    check_positive(minimum_key, minimum);
    if (!std::isfinite(maximum)) {
      add(maximum_key, maximum, "finite");
    } else if (std::isfinite(minimum) && !(maximum > minimum)) {
      add(maximum_key, maximum,
          "greater than " + std::string(minimum_key) + " = " + to_text(minimum));
    }
  }

  std::vector<std::string> take() { return std::move(messages_); }

 private:
  std::vector<std::string> messages_;
};

}  // namespace

StereoNoise StereoNoise::isotropic(double sigma) {
  const double root_two = std::sqrt(2.0);
  return {sigma / root_two, sigma / root_two, sigma * root_two, sigma * root_two};
}

std::array<double, 3> body_axis_vector(const std::string& axis) {
  std::array<double, 3> out{0.0, 0.0, 0.0};
  if (axis.size() != 2 || (axis[0] != '+' && axis[0] != '-')) return out;
  const double sign = axis[0] == '+' ? 1.0 : -1.0;
  if (axis[1] < 'x' || axis[1] > 'z') return out;
  out[static_cast<std::size_t>(axis[1] - 'x')] = sign;
  return out;
}

EstimatorOptions::DetectionErrorState EstimatorOptions::detection_error_state() const {
  if (object_displacement_sigma[0] > 0.0 || object_displacement_sigma[1] > 0.0 ||
      object_displacement_sigma[2] > 0.0) {
    return DetectionErrorState::kDisplacement;
  }
  if (object_offset_sigma.horizontal > 0.0 || object_offset_sigma.vertical > 0.0 ||
      object_offset_sigma.disparity > 0.0) {
    return DetectionErrorState::kImageOffset;
  }
  return DetectionErrorState::kNone;
}

std::vector<std::string> EstimatorOptions::validate() const {
  Problems problems;
  problems.check_at_least("window_size", window_size, 2);
  problems.check_positive("initial_position_sigma", initial_position_sigma);
  problems.check_positive("initial_rotation_sigma", initial_rotation_sigma);
  problems.check_positive("odometry_translation_sigma", odometry_translation_sigma);
  problems.check_positive("odometry_rotation_sigma", odometry_rotation_sigma);
  if (!(std::isfinite(odometry_translation_scale) && odometry_translation_scale > 0.5 &&
        odometry_translation_scale < 2.0)) {
    problems.add("odometry_translation_scale", odometry_translation_scale, "in (0.5, 2)");
  }

  if (!(std::isfinite(disparity_offset_sigma) && disparity_offset_sigma >= 0.0)) {
    problems.add("disparity_offset_sigma", disparity_offset_sigma, "finite and >= 0 (0 disables)");
  }
  if (!(std::isfinite(level_sigma) && level_sigma >= 0.0)) {
    problems.add("level_sigma", level_sigma, "finite and >= 0 (0 disables)");
  }
  problems.check_at_least("level_every_frames", level_every_frames, 1);
  const double up_norm = std::hypot(level_up_axis[0], level_up_axis[1], level_up_axis[2]);
  if (!(std::isfinite(up_norm) && up_norm > 0.5 && up_norm < 2.0)) {
    problems.add("level_up_axis", level_up_axis, "a body direction of about unit length");
  }
  problems.check_stereo_noise("object_noise", object_noise);
  for (const auto& [name, noise] : {std::pair{"object_noise_constant", &object_noise_constant},
                                     std::pair{"object_noise_persistent", &object_noise_persistent},
                                     std::pair{"object_offset_sigma", &object_offset_sigma},
                                     std::pair{"object_offset_walk", &object_offset_walk}}) {
    for (const auto& [part, value] : {std::pair{".horizontal", noise->horizontal},
                                      std::pair{".vertical", noise->vertical},
                                      std::pair{".disparity", noise->disparity},
                                      std::pair{".vertical_disparity", noise->vertical_disparity}}) {
      if (!(std::isfinite(value) && value >= 0.0)) {
        problems.add(std::string(name) + part, value, "finite and >= 0");
      }
    }
  }
  const auto any = [](const StereoNoise& n) {
    return n.horizontal > 0.0 || n.vertical > 0.0 || n.disparity > 0.0;
  };
  if (any(object_offset_sigma) &&
      (any(object_noise_constant) || object_noise_constant.vertical_disparity > 0.0 ||
       any(object_noise_persistent) || object_noise_persistent.vertical_disparity > 0.0)) {
    problems.add("object_offset_sigma", object_offset_sigma.horizontal,
                 "zero with object_noise_constant or object_noise_persistent (two models of one "
                 "error)");
  }
  const auto any3 = [](const std::array<double, 3>& v) {
    return v[0] > 0.0 || v[1] > 0.0 || v[2] > 0.0;
  };
  for (const auto& [name, values] :
       {std::pair{"object_displacement_sigma", &object_displacement_sigma},
        std::pair{"object_displacement_walk", &object_displacement_walk}}) {
    for (std::size_t axis = 0; axis < 3; ++axis) {
      if (!(std::isfinite((*values)[axis]) && (*values)[axis] >= 0.0)) {
        problems.add(std::string(name) + "[" + std::to_string(axis) + "]", (*values)[axis],
                     "finite and >= 0 (metres)");
      }
    }
  }
  if (any3(object_displacement_sigma) &&
      (any(object_offset_sigma) || any(object_noise_constant) ||
       object_noise_constant.vertical_disparity > 0.0 || any(object_noise_persistent) ||
       object_noise_persistent.vertical_disparity > 0.0)) {
    problems.add("object_displacement_sigma", object_displacement_sigma,
                 "zero with object_offset_sigma, object_noise_constant or "
                 "object_noise_persistent (two models of one error)");
  }
  if (any3(object_displacement_walk) && !any3(object_displacement_sigma)) {
    problems.add("object_displacement_walk", object_displacement_walk,
                 "zero without object_displacement_sigma (the displacement is not a state)");
  }
  if (any(object_offset_walk) && !any(object_offset_sigma)) {
    problems.add("object_offset_walk", object_offset_walk.horizontal,
                 "zero without object_offset_sigma (the offset is not a state)");
  }
  if (!(object_noise_correlation >= 0.0 && object_noise_correlation < 1.0)) {
    problems.add("object_noise_correlation", object_noise_correlation,
                 "in [0, 1) (a constant part is object_noise_constant)");
  }
  problems.check_at_least("object_min_observations", object_min_observations, 2);
  problems.check_distance_range("object_min_distance", object_min_distance, "object_max_distance",
                                object_max_distance);
  problems.check_positive("object_init_max_reprojection_error", object_init_max_reprojection_error);
  if (!(std::isfinite(object_max_relative_sigma) && object_max_relative_sigma >= 0.0)) {
    problems.add("object_max_relative_sigma", object_max_relative_sigma,
                 "finite and >= 0 (0 disables)");
  }
  problems.check_probability("object_chi2_probability", object_chi2_probability);
  problems.check_optional_bound("object_first_estimate_noise", object_first_estimate_noise);
  problems.check_at_least("object_archive_after_frames", object_archive_after_frames, 0);
  if (object_archive_mode != "consider" && object_archive_mode != "marginal") {
    problems.add("object_archive_mode", object_archive_mode, "consider or marginal");
  }

  problems.check_stereo_noise("feature_noise", feature_noise);
  if (!(std::isfinite(feature_drift_sigma) && feature_drift_sigma >= 0.0)) {
    problems.add("feature_drift_sigma", feature_drift_sigma, "finite and >= 0 (0 disables)");
  }
  problems.check_at_least("feature_min_observations", feature_min_observations, 2);
  if (feature_max_observations != 0 && feature_max_observations < feature_min_observations) {
    problems.add("feature_max_observations", feature_max_observations,
                 "0 (the window size) or >= feature_min_observations");
  }
  problems.check_optional_bound("feature_max_reprojection_error", feature_max_reprojection_error);
  problems.check_distance_range("feature_min_distance", feature_min_distance,
                                "feature_max_distance", feature_max_distance);
  problems.check_probability("feature_chi2_probability", feature_chi2_probability);
  for (std::size_t index = 0; index < feature_odometry_correlation.size(); ++index) {
    if (!std::isfinite(feature_odometry_correlation[index])) {
      problems.add("feature_odometry_correlation[" + std::to_string(index) + "]",
                   feature_odometry_correlation[index], "finite");
    }
  }
  if (feature_drift_sigma > 0.0 &&
      std::any_of(feature_odometry_correlation.begin(), feature_odometry_correlation.end(),
                  [](double value) { return value != 0.0; })) {
    problems.add("feature_drift_sigma", feature_drift_sigma,
                 "0 with feature_odometry_correlation (the drift model does not whiten that term)");
  }

  if (!(std::isfinite(consensus.max_condition_number) && consensus.max_condition_number > 1.0)) {
    problems.add("consensus.max_condition_number", consensus.max_condition_number,
                 "finite and > 1");
  }
  if (!(std::isfinite(consensus.fuse_kl_threshold) && consensus.fuse_kl_threshold >= 0.0)) {
    problems.add("consensus.fuse_kl_threshold", consensus.fuse_kl_threshold,
                 "finite and >= 0 (0 fuses every landmark)");
  }
  if (!(std::isfinite(consensus.share_kl_threshold) && consensus.share_kl_threshold >= 0.0)) {
    problems.add("consensus.share_kl_threshold", consensus.share_kl_threshold,
                 "finite and >= 0 (0 sends everything)");
  }
  if (consensus.share_block_landmarks < 0) {
    problems.add("consensus.share_block_landmarks", consensus.share_block_landmarks,
                 ">= 0 (0: joint blocks whole)");
  }
  if (consensus.share_max_landmarks < 0) {
    problems.add("consensus.share_max_landmarks", consensus.share_max_landmarks,
                 ">= 0 (0: no cap)");
  }
  problems.check_probability("consensus.neighbour_chi2_probability",
                             consensus.neighbour_chi2_probability);
  if (consensus.claim_history_rounds < 0) {
    problems.add("consensus.claim_history_rounds", consensus.claim_history_rounds, ">= 0 (0: off)");
  }
  return problems.take();
}

}  // namespace concord
