#pragma once
/// \file
/// EstimatorOptions from and to YAML. The keys are exactly the field names of EstimatorOptions
/// (window_size, object_noise, ...), with a nested map `consensus:` holding the ConsensusOptions
/// field names; object_noise and feature_noise are one number (isotropic) or a map of the
/// StereoNoise components; feature_odometry_correlation is a sequence of 24 numbers (the 6x4
/// matrix, row-major). Example:
///
///     window_size: 30
///     object_noise: {horizontal: 20, vertical: 4, disparity: 2, vertical_disparity: 0.5}
///     consensus:
///       neighbour_chi2_probability: 0.999

#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

#include "concord/association/negotiation.h"
#include "concord/estimator/options.h"

namespace concord::config {

/// A configuration file that cannot be used. The message names the file, and for each problem
/// (one per line) the key and the bad value.
class ConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// The whole text of a configuration file; ConfigError "<file>: cannot open the <what>" if it
/// cannot be read.
std::string read_config_text(const std::filesystem::path& file, const std::string& what);

/// Loads EstimatorOptions from a YAML file (its `association:` section is skipped: see
/// load_negotiation_options). Missing keys keep the in-class defaults; unknown keys
/// (typo protection), repeated keys and values of the wrong type are errors; after loading,
/// EstimatorOptions::validate() runs. Every problem is reported in one ConfigError.
EstimatorOptions load_estimator_options(const std::filesystem::path& file);

/// As load_estimator_options, from YAML text; `source_name` names the text in error messages.
/// Keys the text does not give keep the values of `base` (the in-class defaults unless given).
EstimatorOptions parse_estimator_options(const std::string& yaml_text,
                                         const std::string& source_name,
                                         EstimatorOptions base = {});

/// The options as YAML text with every key, in the format the loader reads (to print at start-up
/// or save next to results). Numbers are written in their shortest exact form, so
/// `options` with each "KEY=VALUE" (YAML value; "consensus.KEY" and "object_noise.horizontal" style
/// keys address nested maps; "association.KEY" entries are left to apply_association_overrides)
/// applied in turn, then validated. Throws ConfigError naming the
/// entry and the problem.
EstimatorOptions apply_overrides(EstimatorOptions options,
                                 const std::vector<std::string>& overrides);

/// parse_estimator_options(to_yaml(options)) gives back the same values.
std::string to_yaml(const EstimatorOptions& options);

/// The association options of a sensor config: its `association:` section (a flat map whose keys
/// are the fields of association::NegotiationOptions and of its AssociationOptions; other
/// sections are ignored), with the same rules as load_estimator_options (defaults for missing
/// keys, unknown keys and wrong types reported, validate() after loading).
association::NegotiationOptions load_negotiation_options(const std::filesystem::path& file);

/// As load_negotiation_options, from YAML text.
association::NegotiationOptions parse_negotiation_options(const std::string& yaml_text,
                                                          const std::string& source_name);

/// `options` with every "association.KEY=VALUE" entry of `overrides` applied (other entries are
/// apply_overrides'), then validated. Throws ConfigError naming the entry and the problem.
association::NegotiationOptions apply_association_overrides(
    association::NegotiationOptions options, const std::vector<std::string>& overrides);

/// The association section as YAML text with every key (parse_negotiation_options reads it back).
std::string to_yaml(const association::NegotiationOptions& options);

}  // namespace concord::config
