#include "concord/config/options_file.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <string>

namespace concord::config {
namespace {

using ::testing::HasSubstr;

/// The ConfigError message of parsing `yaml_text`; fails the test if it throws nothing.
std::string config_error_message(const std::string& yaml_text) {
  try {
    parse_estimator_options(yaml_text, "test.yaml");
  } catch (const ConfigError& error) {
    return error.what();
  }
  ADD_FAILURE() << "expected a ConfigError for:\n" << yaml_text;
  return {};
}

/// Every field differs from its default; the numbers have no short decimal form.
EstimatorOptions unusual_options() {
  EstimatorOptions options;
  options.window_size = 37;
  options.initial_position_sigma = 0.1 + 0.2;
  options.initial_rotation_sigma = 1.0 / 3.0;
  options.odometry_translation_sigma = 2e-7;
  options.odometry_rotation_sigma = 0.0123456789012345678;
  options.use_objects = false;
  options.object_sigma = 4.2;
  options.object_min_observations = 5;
  options.object_min_distance = 1.0 / 7.0;
  options.object_max_distance = 123.456;
  options.object_init_max_reprojection_error = 3.3;
  options.object_update_gate = 0.0;
  options.object_chi2_probability = 0.99;
  options.object_archive_after_frames = 250;
  options.use_point_features = false;
  options.feature_sigma = 0.75;
  options.feature_min_observations = 4;
  options.feature_max_reprojection_error = 2.5;
  options.feature_min_distance = 0.3;
  options.feature_max_distance = 1e3;
  options.feature_chi2_probability = 0.0;
  for (std::size_t index = 0; index < options.feature_odometry_correlation.size(); ++index) {
    options.feature_odometry_correlation[index] = (static_cast<double>(index) - 11.5) / 3.0;
  }
  options.consensus.max_mean_shift = 0.0;
  options.consensus.max_condition_number = 1e15 / 3.0;
  options.consensus.disagreement_gate = 9.21;
  return options;
}

void expect_same_options(const EstimatorOptions& actual, const EstimatorOptions& expected) {
  EXPECT_EQ(actual.window_size, expected.window_size);
  EXPECT_EQ(actual.initial_position_sigma, expected.initial_position_sigma);
  EXPECT_EQ(actual.initial_rotation_sigma, expected.initial_rotation_sigma);
  EXPECT_EQ(actual.odometry_translation_sigma, expected.odometry_translation_sigma);
  EXPECT_EQ(actual.odometry_rotation_sigma, expected.odometry_rotation_sigma);
  EXPECT_EQ(actual.use_objects, expected.use_objects);
  EXPECT_EQ(actual.object_sigma, expected.object_sigma);
  EXPECT_EQ(actual.object_min_observations, expected.object_min_observations);
  EXPECT_EQ(actual.object_min_distance, expected.object_min_distance);
  EXPECT_EQ(actual.object_max_distance, expected.object_max_distance);
  EXPECT_EQ(actual.object_init_max_reprojection_error, expected.object_init_max_reprojection_error);
  EXPECT_EQ(actual.object_update_gate, expected.object_update_gate);
  EXPECT_EQ(actual.object_chi2_probability, expected.object_chi2_probability);
  EXPECT_EQ(actual.object_archive_after_frames, expected.object_archive_after_frames);
  EXPECT_EQ(actual.use_point_features, expected.use_point_features);
  EXPECT_EQ(actual.feature_sigma, expected.feature_sigma);
  EXPECT_EQ(actual.feature_min_observations, expected.feature_min_observations);
  EXPECT_EQ(actual.feature_max_reprojection_error, expected.feature_max_reprojection_error);
  EXPECT_EQ(actual.feature_min_distance, expected.feature_min_distance);
  EXPECT_EQ(actual.feature_max_distance, expected.feature_max_distance);
  EXPECT_EQ(actual.feature_chi2_probability, expected.feature_chi2_probability);
  EXPECT_EQ(actual.feature_odometry_correlation, expected.feature_odometry_correlation);
  EXPECT_EQ(actual.consensus.max_mean_shift, expected.consensus.max_mean_shift);
  EXPECT_EQ(actual.consensus.max_condition_number, expected.consensus.max_condition_number);
  EXPECT_EQ(actual.consensus.disagreement_gate, expected.consensus.disagreement_gate);
}

// --- YAML round trip and loading ---

TEST(OptionsFileTest, DefaultsRoundTrip) {
  const EstimatorOptions defaults;
  const std::string text = to_yaml(defaults);
  expect_same_options(parse_estimator_options(text, "defaults"), defaults);
  EXPECT_THAT(text, HasSubstr("\nwindow_size: 20\n"));
  EXPECT_THAT(text, HasSubstr("\nuse_objects: true\n"));
  EXPECT_THAT(text, HasSubstr("\nconsensus:\n  max_mean_shift: 0.5\n"));
}

TEST(OptionsFileTest, EveryFieldRoundTripsExactly) {
  const EstimatorOptions options = unusual_options();
  ASSERT_TRUE(options.validate().empty());
  const std::string text = to_yaml(options);
  const EstimatorOptions read_back = parse_estimator_options(text, "unusual");
  expect_same_options(read_back, options);
  EXPECT_EQ(to_yaml(read_back), text);
}

TEST(OptionsFileTest, MissingKeysKeepTheDefaults) {
  const EstimatorOptions options =
      parse_estimator_options("window_size: 7\nconsensus:\n  disagreement_gate: 3\n", "partial");
  EXPECT_EQ(options.window_size, 7);
  EXPECT_EQ(options.consensus.disagreement_gate, 3.0);
  EstimatorOptions expected;
  expected.window_size = 7;
  expected.consensus.disagreement_gate = 3.0;
  expect_same_options(options, expected);

  expect_same_options(parse_estimator_options("", "empty"), EstimatorOptions{});
  expect_same_options(parse_estimator_options("# only a comment\n", "comment"), EstimatorOptions{});
}

TEST(OptionsFileTest, LoadsFromAFile) {
  const std::filesystem::path file = std::filesystem::path(::testing::TempDir()) /
                                     ("concord_options_" + std::to_string(::getpid()) + ".yaml");
  {
    std::ofstream stream(file);
    stream << to_yaml(unusual_options());
  }
  expect_same_options(load_estimator_options(file), unusual_options());
  std::filesystem::remove(file);

  try {
    load_estimator_options(file);
    ADD_FAILURE() << "expected a ConfigError";
  } catch (const ConfigError& error) {
    EXPECT_THAT(error.what(), HasSubstr(file.string()));
  }
}

// --- Errors ---

TEST(OptionsFileTest, UnknownKeyIsAnError) {
  const std::string message = config_error_message("window_size: 5\nwindw_size: 3\n");
  EXPECT_THAT(message, HasSubstr("test.yaml"));
  EXPECT_THAT(message, HasSubstr("line 2: unknown key windw_size"));

  EXPECT_THAT(config_error_message("consensus:\n  max_shift: 1\n"),
              HasSubstr("line 2: unknown key consensus.max_shift"));
}

TEST(OptionsFileTest, RepeatedKeyIsAnError) {
  EXPECT_THAT(config_error_message("window_size: 5\nwindow_size: 6\n"),
              HasSubstr("line 2: key window_size appears more than once"));
}

TEST(OptionsFileTest, WrongTypeIsAnError) {
  EXPECT_THAT(config_error_message("window_size: 3.5\n"), HasSubstr("test.yaml"));
  EXPECT_THAT(config_error_message("window_size: 3.5\n"),
              HasSubstr("line 1: window_size = '3.5': expected an integer"));
  EXPECT_THAT(config_error_message("object_sigma: five\n"),
              HasSubstr("object_sigma = 'five': expected a number"));
  EXPECT_THAT(config_error_message("use_objects: maybe\n"),
              HasSubstr("use_objects = 'maybe': expected true or false"));
  EXPECT_THAT(config_error_message("object_sigma: [1, 2]\n"),
              HasSubstr("object_sigma = a sequence: expected a number"));
  EXPECT_THAT(config_error_message("object_sigma:\n"),
              HasSubstr("object_sigma = nothing (null): expected a number"));
  EXPECT_THAT(config_error_message("feature_odometry_correlation: [1, 2, 3]\n"),
              HasSubstr("feature_odometry_correlation = a sequence of 3 entries: expected a "
                        "sequence of 24 numbers"));
  EXPECT_THAT(config_error_message("consensus: 3\n"), HasSubstr("consensus = '3': expected a map"));
  EXPECT_THAT(config_error_message("consensus:\n  max_mean_shift: far\n"),
              HasSubstr("line 2: consensus.max_mean_shift = 'far': expected a number"));
  EXPECT_THAT(config_error_message("- window_size\n"), HasSubstr("expected a map of option keys"));

  std::string correlation = "feature_odometry_correlation: [";
  for (int index = 0; index < 24; ++index) correlation += index == 17 ? "x, " : "0, ";
  EXPECT_THAT(config_error_message(correlation + "]\n"),
              HasSubstr("feature_odometry_correlation[17] = 'x': expected a number"));
}

TEST(OptionsFileTest, InvalidValueIsAnError) {
  const std::string message = config_error_message("window_size: 1\n");
  EXPECT_THAT(message, HasSubstr("test.yaml"));
  EXPECT_THAT(message, HasSubstr("window_size = 1: must be >= 2"));
  EXPECT_THAT(config_error_message("consensus:\n  max_condition_number: 0.5\n"),
              HasSubstr("consensus.max_condition_number = 0.5: must be finite and > 1"));
  EXPECT_THAT(config_error_message("object_sigma: .nan\n"),
              HasSubstr("object_sigma = nan: must be finite and > 0"));
}

TEST(OptionsFileTest, EveryProblemIsReportedAtOnce) {
  const std::string message =
      config_error_message("windw_size: 3\nobject_sigma: -1\nuse_objects: 2\n");
  EXPECT_THAT(message, HasSubstr("unknown key windw_size"));
  EXPECT_THAT(message, HasSubstr("object_sigma = -1"));
  EXPECT_THAT(message, HasSubstr("use_objects = '2'"));
}

TEST(OptionsFileTest, InvalidYamlSyntax) {
  const std::string message = config_error_message("window_size: [1, 2\n");
  EXPECT_THAT(message, HasSubstr("test.yaml:"));
  EXPECT_THAT(message, HasSubstr("invalid YAML"));
}

// --- validate() ---

TEST(OptionsValidateTest, DefaultsAreValid) { EXPECT_TRUE(EstimatorOptions{}.validate().empty()); }

TEST(OptionsValidateTest, BoundariesThatDisableAreValid) {
  EstimatorOptions options;
  options.object_update_gate = 0.0;
  options.object_chi2_probability = 0.0;
  options.feature_chi2_probability = 0.0;
  options.object_archive_after_frames = 0;
  options.window_size = 2;
  options.object_min_observations = 2;
  options.consensus.max_mean_shift = 0.0;
  options.consensus.disagreement_gate = 0.0;
  EXPECT_TRUE(options.validate().empty());
}

struct ValidationCase {
  std::string description;
  std::function<void(EstimatorOptions&)> change;
  /// The one message expected, in part: the key, the bad value and the accepted range.
  std::string expected_message;
};

TEST(OptionsValidateTest, EachRuleNamesTheKeyTheValueAndTheRange) {
  constexpr double kNan = std::numeric_limits<double>::quiet_NaN();
  constexpr double kInfinity = std::numeric_limits<double>::infinity();
  const std::vector<ValidationCase> cases = {
      {"window", [](auto& o) { o.window_size = 1; }, "window_size = 1: must be >= 2"},
      {"sigma zero", [](auto& o) { o.initial_position_sigma = 0; },
       "initial_position_sigma = 0: must be finite and > 0"},
      {"sigma negative", [](auto& o) { o.initial_rotation_sigma = -1; },
       "initial_rotation_sigma = -1: must be finite and > 0"},
      {"sigma infinite", [&](auto& o) { o.odometry_translation_sigma = kInfinity; },
       "odometry_translation_sigma = inf: must be finite and > 0"},
      {"sigma nan", [&](auto& o) { o.odometry_rotation_sigma = kNan; },
       "odometry_rotation_sigma = nan: must be finite and > 0"},
      {"object sigma", [](auto& o) { o.object_sigma = 0; },
       "object_sigma = 0: must be finite and > 0"},
      {"feature sigma", [](auto& o) { o.feature_sigma = -0.5; },
       "feature_sigma = -0.5: must be finite and > 0"},
      {"object observations", [](auto& o) { o.object_min_observations = 1; },
       "object_min_observations = 1: must be >= 2"},
      {"feature observations", [](auto& o) { o.feature_min_observations = 0; },
       "feature_min_observations = 0: must be >= 2"},
      {"object min distance", [](auto& o) { o.object_min_distance = 0; },
       "object_min_distance = 0: must be finite and > 0"},
      {"object max distance", [](auto& o) { o.object_max_distance = 5; },
       "object_max_distance = 5: must be greater than object_min_distance = 5"},
      {"feature min distance", [](auto& o) { o.feature_min_distance = -1; },
       "feature_min_distance = -1: must be finite and > 0"},
      {"feature max distance", [](auto& o) { o.feature_max_distance = 0.25; },
       "feature_max_distance = 0.25: must be greater than feature_min_distance = 0.5"},
      {"feature max distance infinite", [&](auto& o) { o.feature_max_distance = kInfinity; },
       "feature_max_distance = inf: must be finite"},
      {"object reprojection", [](auto& o) { o.object_init_max_reprojection_error = 0; },
       "object_init_max_reprojection_error = 0: must be finite and > 0"},
      {"feature reprojection", [](auto& o) { o.feature_max_reprojection_error = -1; },
       "feature_max_reprojection_error = -1: must be finite and > 0"},
      {"gate", [](auto& o) { o.object_update_gate = -1; },
       "object_update_gate = -1: must be finite and >= 0"},
      {"object chi2", [](auto& o) { o.object_chi2_probability = 1; },
       "object_chi2_probability = 1: must be in [0, 1)"},
      {"feature chi2", [](auto& o) { o.feature_chi2_probability = -0.1; },
       "feature_chi2_probability = -0.1: must be in [0, 1)"},
      {"archive", [](auto& o) { o.object_archive_after_frames = -1; },
       "object_archive_after_frames = -1: must be >= 0"},
      {"correlation", [&](auto& o) { o.feature_odometry_correlation[5] = kNan; },
       "feature_odometry_correlation[5] = nan: must be finite"},
      {"mean shift", [](auto& o) { o.consensus.max_mean_shift = -0.1; },
       "consensus.max_mean_shift = -0.1: must be finite and >= 0"},
      {"condition number", [](auto& o) { o.consensus.max_condition_number = 1; },
       "consensus.max_condition_number = 1: must be finite and > 1"},
      {"disagreement gate", [](auto& o) { o.consensus.disagreement_gate = -2; },
       "consensus.disagreement_gate = -2: must be finite and >= 0"},
  };
  for (const ValidationCase& test_case : cases) {
    SCOPED_TRACE(test_case.description);
    EstimatorOptions options;
    test_case.change(options);
    const std::vector<std::string> problems = options.validate();
    ASSERT_EQ(problems.size(), 1u) << ::testing::PrintToString(problems);
    EXPECT_THAT(problems[0], HasSubstr(test_case.expected_message));
  }
}

TEST(OptionsValidateTest, ReportsEveryProblem) {
  EstimatorOptions options;
  options.window_size = 0;
  options.object_sigma = -1;
  options.consensus.max_mean_shift = -1;
  EXPECT_EQ(options.validate().size(), 3u);
}

}  // namespace
}  // namespace concord::config
