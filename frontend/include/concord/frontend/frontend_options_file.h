#pragma once
/// \file
/// FrontendOptions from and to YAML: three maps, `tracker:`, `odometry:` and `objects:`, whose
/// keys are the field names of TrackerOptions, OdometryOptions and ObjectOptions. Example:
///
///     tracker:
///       target_features: 300
///     odometry:
///       pixel_sigma: 0.3
///
/// Missing keys keep the defaults; unknown keys (typo protection) and values of the wrong type
/// are errors; FrontendOptions::validate() runs after loading. Every problem is reported at once.

#include <filesystem>
#include <string>

#include "concord/frontend/frontend_options.h"

namespace concord::frontend {

/// Throws FrontendError listing every problem, each naming the key (and line).
[[nodiscard]] FrontendOptions parse_frontend_options(const std::string& yaml_text,
                                                     const std::string& source_name);

/// Reads a file; FrontendError if it cannot be read or is invalid.
[[nodiscard]] FrontendOptions load_frontend_options(const std::filesystem::path& file);

/// Every option as YAML in the format the loader reads; numbers in their shortest exact form.
std::string to_yaml(const FrontendOptions& options);

}  // namespace concord::frontend
