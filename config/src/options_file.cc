#include "concord/config/options_file.h"

#include "concord/config/yaml_section.h"

#include <yaml-cpp/yaml.h>

#include <array>
#include <charconv>
#include <cmath>
#include <fstream>
#include <iterator>
#include <set>
#include <string_view>
#include <vector>

namespace concord::config {

namespace {

constexpr std::string_view kConsensusKey = "consensus";
/// The section of a sensor config read by load_negotiation_options (skipped by the estimator's).
constexpr std::string_view kAssociationKey = "association";

/// Calls visit(key, field) for every association option (NegotiationOptions and its
/// AssociationOptions, one flat namespace): the one list of association keys.
template <typename Negotiation, typename Visitor>
void for_each_association_field(Negotiation& options, Visitor&& visit) {
  auto& association = options.association;
  visit("min_observations", association.min_observations);
  visit("min_detection_ratio", association.min_detection_ratio);
  visit("search_max_sigma", association.search_max_sigma);
  visit("archived_local_covariance", association.archived_local_covariance);
  visit("descriptor_neighbours", association.descriptor_neighbours);
  visit("descriptor_chi2_probability", association.descriptor_chi2_probability);
  visit("candidates_per_object", association.candidates_per_object);
  visit("min_descriptor_matches", association.min_descriptor_matches);
  visit("consistency_chi2_probability", association.consistency_chi2_probability);
  visit("distance_noise", association.distance_noise);
  visit("min_inliers", association.min_inliers);
  visit("min_spread", association.min_spread);
  visit("ambiguity_ratio", association.ambiguity_ratio);
  visit("match_chi2_probability", association.match_chi2_probability);
  visit("match_margin", association.match_margin);
  visit("max_hypotheses", association.max_hypotheses);
  visit("max_candidates", association.max_candidates);
  visit("max_clique_expansions", association.max_clique_expansions);
  visit("use_classes", association.use_classes);
  visit("start_up_axis", association.start_up_axis);
  visit("max_start_tilt", association.max_start_tilt);
  visit("description_interval", options.description_interval);
  visit("confirmations", options.confirmations);
  visit("confirmation_new_matches", options.confirmation_new_matches);
  visit("transform_agreement_chi2_probability", options.transform_agreement_chi2_probability);
  visit("split_chi2_probability", options.split_chi2_probability);
  visit("split_after", options.split_after);
  visit("revisit_descriptions", options.revisit_descriptions);
  visit("revisit_interval", options.revisit_interval);
  visit("revisit_confirmations", options.revisit_confirmations);
  visit("revisit_chi2_probability", options.revisit_chi2_probability);
  visit("revisit_ambiguity_ratio", options.revisit_ambiguity_ratio);
  visit("max_corrections", options.max_corrections);
  visit("relay_delay", options.relay_delay);
  visit("in_frame_fit", options.in_frame_fit);
  visit("in_frame_current_pass", options.in_frame_current_pass);
  visit("in_frame_search", options.in_frame_search);
}

/// Calls visit(key, field) for every field of ConsensusOptions (const or not): the one list of
/// consensus keys, shared by the loader and the writer.
template <typename Consensus, typename Visitor>
void for_each_consensus_field(Consensus& consensus, Visitor&& visit) {
  visit("max_condition_number", consensus.max_condition_number);
  visit("neighbour_chi2_probability", consensus.neighbour_chi2_probability);
  visit("claim_history_rounds", consensus.claim_history_rounds);
  visit("fuse_kl_threshold", consensus.fuse_kl_threshold);
  visit("share_kl_threshold", consensus.share_kl_threshold);
  visit("share_max_landmarks", consensus.share_max_landmarks);
  visit("share_float32", consensus.share_float32);
  visit("share_block_landmarks", consensus.share_block_landmarks);
}

/// Calls visit(key, field) for every component of a StereoNoise.
template <typename Noise, typename Visitor>
void for_each_noise_field(Noise& noise, Visitor&& visit) {
  visit("horizontal", noise.horizontal);
  visit("vertical", noise.vertical);
  visit("disparity", noise.disparity);
  visit("vertical_disparity", noise.vertical_disparity);
}

/// Calls visit(key, field) for every top-level field of EstimatorOptions except `consensus`, in
/// declaration order: the one list of keys, shared by the loader and the writer.
template <typename Options, typename Visitor>
void for_each_field(Options& options, Visitor&& visit) {
  visit("window_size", options.window_size);
  visit("initial_position_sigma", options.initial_position_sigma);
  visit("initial_rotation_sigma", options.initial_rotation_sigma);
  visit("odometry_translation_sigma", options.odometry_translation_sigma);
  visit("odometry_rotation_sigma", options.odometry_rotation_sigma);
  visit("odometry_translation_scale", options.odometry_translation_scale);
  visit("disparity_offset_sigma", options.disparity_offset_sigma);
  visit("level_sigma", options.level_sigma);
  visit("level_every_frames", options.level_every_frames);
  visit("level_up_axis", options.level_up_axis);
  visit("use_objects", options.use_objects);
  visit("object_noise", options.object_noise);
  visit("object_noise_constant", options.object_noise_constant);
  visit("object_noise_persistent", options.object_noise_persistent);
  visit("object_noise_correlation", options.object_noise_correlation);
  visit("object_offset_sigma", options.object_offset_sigma);
  visit("object_offset_walk", options.object_offset_walk);
  visit("object_displacement_sigma", options.object_displacement_sigma);
  visit("object_displacement_walk", options.object_displacement_walk);
  visit("object_min_observations", options.object_min_observations);
  visit("object_min_distance", options.object_min_distance);
  visit("object_max_distance", options.object_max_distance);
  visit("object_max_relative_sigma", options.object_max_relative_sigma);
  visit("object_init_max_reprojection_error", options.object_init_max_reprojection_error);
  visit("object_chi2_probability", options.object_chi2_probability);
  visit("object_first_estimate_noise", options.object_first_estimate_noise);
  visit("object_archive_after_frames", options.object_archive_after_frames);
  visit("object_archive_mode", options.object_archive_mode);
  visit("use_point_features", options.use_point_features);
  visit("feature_noise", options.feature_noise);
  visit("feature_drift_sigma", options.feature_drift_sigma);
  visit("feature_min_observations", options.feature_min_observations);
  visit("feature_max_observations", options.feature_max_observations);
  visit("feature_max_reprojection_error", options.feature_max_reprojection_error);
  visit("feature_min_distance", options.feature_min_distance);
  visit("feature_max_distance", options.feature_max_distance);
  visit("feature_chi2_probability", options.feature_chi2_probability);
  visit("feature_odometry_correlation", options.feature_odometry_correlation);
}

using Correlation = decltype(EstimatorOptions::feature_odometry_correlation);

/// Reads the option maps with the project's one YAML reader (yaml_section.h): every key a
/// for_each_* list names, a key given with no value included (an error), then the unknown ones.
void read_node(YamlSection& section, const YAML::Node& value, const std::string& key, int& field) {
  section.read_value(value, key, field, "an integer");
}
void read_node(YamlSection& section, const YAML::Node& value, const std::string& key,
               double& field) {
  section.read_value(value, key, field, "a number");
}
void read_node(YamlSection& section, const YAML::Node& value, const std::string& key, bool& field) {
  section.read_value(value, key, field, "true or false");
}
void read_node(YamlSection& section, const YAML::Node& value, const std::string& key,
               std::string& field) {
  section.read_value(value, key, field, "a string");
}
void read_node(YamlSection& section, const YAML::Node& node, const std::string& key,
               Correlation& field) {
  if (!node.IsSequence() || node.size() != field.size()) {
    const std::string found = node.IsSequence()
                                  ? "a sequence of " + std::to_string(node.size()) + " entries"
                                  : describe(node);
    section.add(line_of(node) + key + " = " + found + ": expected a sequence of " +
                std::to_string(field.size()) + " numbers");
    return;
  }
  Correlation values = field;
  bool all_read = true;
  for (std::size_t index = 0; index < values.size(); ++index) {
    all_read &= section.read_value(node[index], key + "[" + std::to_string(index) + "]",
                                   values[index], "a number");
  }
  if (all_read) field = values;
}

/// Three numbers; for a body direction (a key ending in "_axis") also a named axis ("+z").
void read_node(YamlSection& section, const YAML::Node& node, const std::string& key,
               std::array<double, 3>& field) {
  const bool direction = key.size() >= 5 && key.compare(key.size() - 5, 5, "_axis") == 0;
  const std::string expected =
      direction ? "+x, -x, +y, -y, +z, -z or a sequence [x, y, z]" : "a sequence of 3 numbers";
  if (node.IsScalar()) {
    if (!direction) return section.problem(node, key, expected);
    std::string name;
    if (!section.read_value(node, key, name, expected)) return;
    const std::array<double, 3> axis = body_axis_vector(name);
    if (axis == std::array<double, 3>{0.0, 0.0, 0.0}) return section.problem(node, key, expected);
    field = axis;
    return;
  }
  if (!node.IsSequence() || node.size() != field.size()) return section.problem(node, key, expected);
  std::array<double, 3> values = field;
  bool all_read = true;
  for (std::size_t index = 0; index < values.size(); ++index) {
    all_read &= section.read_value(node[index], key + "[" + std::to_string(index) + "]",
                                   values[index], "a number");
  }
  if (all_read) field = values;
}

template <typename Options, typename ForEach>
void read_map(YamlSection& section, Options& options, ForEach&& for_each);

/// A StereoNoise: one number (isotropic) or a map of its four components.
void read_node(YamlSection& section, const YAML::Node& node, const std::string& key,
               StereoNoise& field) {
  const std::string expected = "a number or a map of noise components";
  if (node.IsScalar()) {
    double sigma = 0.0;
    if (section.read_value(node, key, sigma, expected)) field = StereoNoise::isotropic(sigma);
    return;
  }
  if (!node.IsMap()) return section.problem(node, key, expected);
  YamlSection noise_section(node, key + ".", section.problems());
  StereoNoise noise = field;
  read_map(noise_section, noise, [](auto& target, auto&& visit) {
    for_each_noise_field(target, visit);
  });
  noise_section.finish();
  field = noise;
}

/// Reads every field that `for_each(options, visit)` names from `section`.
template <typename Options, typename ForEach>
void read_map(YamlSection& section, Options& options, ForEach&& for_each) {
  for_each(options, [&](std::string_view name, auto& field) {
    const std::string key(name);
    const YAML::Node value = section.child(key);
    if (value) read_node(section, value, section.prefix() + key, field);
  });
}

/// The top-level map of estimator options (its association section is left to
/// read_association_section).
void read_options(YamlSection& top, EstimatorOptions& options) {
  read_map(top, options, [](auto& target, auto&& visit) { for_each_field(target, visit); });
  if (const YAML::Node map = top.child(std::string(kConsensusKey))) {
    YamlSection consensus(map, std::string(kConsensusKey) + ".", top.problems(),
                          "a map of consensus options");
    read_map(consensus, options.consensus,
             [](auto& target, auto&& visit) { for_each_consensus_field(target, visit); });
    consensus.finish();
  }
  top.child(std::string(kAssociationKey));
  top.finish();
}

/// The `association:` section of a map of option keys (other keys are not looked at).
void read_association_section(YamlSection& top, association::NegotiationOptions& options) {
  const YAML::Node map = top.child(std::string(kAssociationKey));
  if (!map) return;
  YamlSection section(map, std::string(kAssociationKey) + ".", top.problems(),
                      "a map of association options");
  read_map(section, options,
           [](auto& target, auto&& visit) { for_each_association_field(target, visit); });
  section.finish();
}

/// Shortest YAML text that reads back as exactly `value`.
std::string format_number(double value) {
  if (std::isnan(value)) return ".nan";
  if (std::isinf(value)) return value > 0.0 ? ".inf" : "-.inf";
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  return std::string(buffer, result.ptr);
}

std::string format_value(int value) { return std::to_string(value); }
std::string format_value(double value) { return format_number(value); }
std::string format_value(bool value) { return value ? "true" : "false"; }
std::string format_value(const std::string& value) { return value; }
/// Flow map of the four components.
std::string format_value(const StereoNoise& noise) {
  std::string text = "{";
  for_each_noise_field(noise, [&](std::string_view key, double value) {
    if (text.size() > 1) text += ", ";
    text += std::string(key) + ": " + format_number(value);
  });
  return text + "}";
}

/// Flow sequence.
std::string format_value(const std::array<double, 3>& values) {
  return "[" + format_number(values[0]) + ", " + format_number(values[1]) + ", " +
         format_number(values[2]) + "]";
}

/// Flow sequence, one row of the 6x4 matrix per line.
std::string format_value(const Correlation& values) {
  constexpr std::size_t kColumns = 4;
  std::string text = "[";
  for (std::size_t index = 0; index < values.size(); ++index) {
    if (index > 0) text += index % kColumns == 0 ? ",\n  " : ", ";
    text += format_number(values[index]);
  }
  return text + "]";
}

}  // namespace

namespace {

/// Throws ConfigError naming source_name, `what` and every problem, if there are any.
void throw_problems(const std::vector<std::string>& problems, const std::string& source_name,
                    const std::string& what) {
  if (problems.empty()) return;
  std::string message = source_name + ": invalid " + what + ":";
  for (const std::string& problem : problems) message += "\n  " + problem;
  throw ConfigError(message);
}

/// Reads YAML text into `options` with `read` (keys not given keep their value) and, with
/// `validate`, checks the result as a whole; throws ConfigError naming every problem.
template <typename Options, typename Read>
void read_validated(Options& options, const std::string& yaml_text, const std::string& source_name,
                    const std::string& what, Read read, bool validate = true) {
  const YAML::Node root = load_yaml(yaml_text, source_name);
  std::vector<std::string> problems;
  YamlSection top(root, "", problems, "a map of option keys");
  read(top);
  if (validate) {
    for (const std::string& problem : options.validate()) problems.push_back(problem);
  }
  throw_problems(problems, source_name, what);
}

void read_into(EstimatorOptions& options, const std::string& yaml_text,
               const std::string& source_name, bool validate = true) {
  read_validated(
      options, yaml_text, source_name, "estimator options",
      [&](YamlSection& top) { read_options(top, options); }, validate);
}

/// "--set A --set B ..." of the entries that `applies` picks: the source of a problem that only
/// their combination has.
template <typename Applies>
std::string overrides_name(const std::vector<std::string>& overrides, Applies applies) {
  std::string name;
  for (const std::string& entry : overrides) {
    if (applies(entry)) name += (name.empty() ? "--set " : " --set ") + entry;
  }
  return name;
}

}  // namespace

EstimatorOptions parse_estimator_options(const std::string& yaml_text,
                                         const std::string& source_name, EstimatorOptions base) {
  read_into(base, yaml_text, source_name);
  return base;
}

namespace {

/// Reads the association section of YAML text into `options`, then validates; throws ConfigError
/// naming source_name and every problem.
void read_association_into(association::NegotiationOptions& options, const std::string& yaml_text,
                           const std::string& source_name, bool validate = true) {
  read_validated(
      options, yaml_text, source_name, "association options",
      [&](YamlSection& top) { read_association_section(top, options); }, validate);
}

bool is_association_override(const std::string& entry) {
  return entry.starts_with(std::string(kAssociationKey) + ".");
}

}  // namespace

association::NegotiationOptions parse_negotiation_options(const std::string& yaml_text,
                                                          const std::string& source_name) {
  association::NegotiationOptions options;
  read_association_into(options, yaml_text, source_name);
  return options;
}

association::NegotiationOptions load_negotiation_options(const std::filesystem::path& file) {
  return parse_negotiation_options(read_config_text(file, "options file"), file.string());
}

association::NegotiationOptions apply_association_overrides(
    association::NegotiationOptions options, const std::vector<std::string>& overrides) {
  for (const std::string& entry : overrides) {
    if (!is_association_override(entry)) continue;
    const auto equals = entry.find('=');
    if (equals == std::string::npos) throw ConfigError("--set " + entry + ": expected KEY=VALUE");
    const std::string key = entry.substr(0, equals);
    const std::string yaml = std::string(kAssociationKey) + ":\n  " +
                             key.substr(kAssociationKey.size() + 1) + ": " +
                             entry.substr(equals + 1) + "\n";
    read_association_into(options, yaml, "--set " + entry, /*validate=*/false);
  }
  // Validated as a whole: entries that are valid only together may come in any order.
  throw_problems(options.validate(), overrides_name(overrides, is_association_override),
                 "association options");
  return options;
}

std::string to_yaml(const association::NegotiationOptions& options) {
  std::string text = std::string(kAssociationKey) + ":\n";
  for_each_association_field(options, [&](std::string_view key, const auto& field) {
    text += "  " + std::string(key) + ": " + format_value(field) + "\n";
  });
  return text;
}

EstimatorOptions apply_overrides(EstimatorOptions options,
                                 const std::vector<std::string>& overrides) {
  for (const std::string& entry : overrides) {
    if (is_association_override(entry)) continue;
    const auto equals = entry.find('=');
    if (equals == std::string::npos || equals == 0) {
      throw ConfigError("--set " + entry + ": expected KEY=VALUE");
    }
    const std::string key = entry.substr(0, equals);
    const std::string value = entry.substr(equals + 1);
    std::string yaml;
    if (const auto dot = key.find('.'); dot != std::string::npos) {
      yaml = key.substr(0, dot) + ":\n  " + key.substr(dot + 1) + ": " + value + "\n";
    } else {
      yaml = key + ": " + value + "\n";
    }
    read_into(options, yaml, "--set " + entry, /*validate=*/false);
  }
  // Validated as a whole: entries that are valid only together (an offset's sigma and walk set
  // to zero) may come in any order.
  throw_problems(
      options.validate(),
      overrides_name(overrides,
                     [](const std::string& entry) { return !is_association_override(entry); }),
      "estimator options");
  return options;
}

std::string read_config_text(const std::filesystem::path& file, const std::string& what) {
  std::ifstream stream(file, std::ios::binary);
  if (!stream || !std::filesystem::is_regular_file(file)) {
    throw ConfigError(file.string() + ": cannot open the " + what);
  }
  return std::string((std::istreambuf_iterator<char>(stream)), std::istreambuf_iterator<char>());
}

EstimatorOptions load_estimator_options(const std::filesystem::path& file) {
  return parse_estimator_options(read_config_text(file, "options file"), file.string());
}

std::string to_yaml(const EstimatorOptions& options) {
  std::string text =
      "# Estimator options: the keys are the fields of concord::EstimatorOptions\n"
      "# (estimator/include/concord/estimator/options.h).\n";
  for_each_field(options, [&](std::string_view key, const auto& field) {
    text += std::string(key) + ": " + format_value(field) + "\n";
  });
  text += std::string(kConsensusKey) + ":\n";
  for_each_consensus_field(options.consensus, [&](std::string_view key, const auto& field) {
    text += "  " + std::string(key) + ": " + format_value(field) + "\n";
  });
  return text;
}

}  // namespace concord::config
