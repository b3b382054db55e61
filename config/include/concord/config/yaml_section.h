#pragma once
/// \file
/// The one YAML map reader of the project's configuration files (estimator options, daemon
/// configs, front-end options): reads the keys a loader asks for into typed fields, collects every
/// problem with its line instead of stopping at the first, and reports the keys nobody asked for
/// (typos), keys given twice and keys that are not plain names. Messages read
///   "line 3: source.rate_hz = 'fast': expected a number", "line 7: unknown key http.prot".
/// Include only from the loaders' .cc files (it brings yaml-cpp).

#include <yaml-cpp/yaml.h>

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <set>
#include <string>
#include <vector>

namespace concord::config {

/// "line N: " of a node (yaml-cpp counts from 0), or "" when unknown.
std::string line_of(const YAML::Node& node);

/// A node as a user wrote it, for messages: 'text', a sequence, a map, nothing (null).
std::string describe(const YAML::Node& node);

/// Parses YAML text; ConfigError "<source_name>:<line>: invalid YAML: ..." if it cannot.
YAML::Node load_yaml(const std::string& yaml_text, const std::string& source_name);

/// One map of a configuration file.
class YamlSection {
 public:
  /// `node`: the map (missing or null: an empty one); `prefix`: "" or "name." in front of its
  /// keys in messages; `expected`: what it should be, for the message when it is not a map.
  YamlSection(const YAML::Node& node, std::string prefix, std::vector<std::string>& problems,
              const std::string& expected = "a map");

  /// The value node of `key` (an invalid node if absent), and `key` is known from now on.
  YAML::Node child(const std::string& key);
  /// Whether the map has `key` with a non-null value (marks it known).
  bool has(const std::string& key) { return present(child(key)); }

  /// Reads a scalar into `field` if the key is there (else the field keeps its value); a value of
  /// the wrong type is a problem and leaves the field. True when a value was read.
  bool read(const std::string& key, int& field) { return read_scalar(key, field, "an integer"); }
  bool read(const std::string& key, double& field) { return read_scalar(key, field, "a number"); }
  bool read(const std::string& key, bool& field) { return read_scalar(key, field, "true or false"); }
  bool read(const std::string& key, std::string& field) {
    return read_scalar(key, field, "a string");
  }
  /// A path, relative to `base` unless absolute.
  void read(const std::string& key, std::filesystem::path& field, const std::filesystem::path& base);
  void read_port(const std::string& key, std::uint16_t& field, bool allow_zero);
  void read_milliseconds(const std::string& key, std::chrono::milliseconds& field, bool allow_zero);
  /// A positive integer (a size or a limit).
  void read_size(const std::string& key, std::size_t& field);
  void read_ints(const std::string& key, std::vector<int>& field);
  void read_strings(const std::string& key, std::vector<std::string>& field);
  /// Exactly `count` numbers.
  void read_numbers(const std::string& key, std::vector<double>& field, std::size_t count);

  /// Reads the scalar `value` (e.g. an element of a sequence); `key` is its name in messages,
  /// prefix included.
  template <typename Value>
  bool read_value(const YAML::Node& value, const std::string& key, Value& field,
                  const std::string& expected) {
    if (value.IsScalar()) {
      try {
        field = value.as<Value>();
        return true;
      } catch (const YAML::BadConversion&) {
      }
    }
    problem(value, key, expected);
    return false;
  }

  /// Adds "line: <key> = <value>: expected <expected>" (`key` with its prefix).
  void problem(const YAML::Node& value, const std::string& key, const std::string& expected);
  /// Adds a message as it is.
  void add(const std::string& message) { problems_.push_back(message); }

  const std::string& prefix() const { return prefix_; }
  /// Where the problems go (for the sections inside this one).
  std::vector<std::string>& problems() { return problems_; }
  /// Whether the node was a map (or absent).
  bool valid() const { return valid_; }

  /// Reports every key of the map that was never asked for, given twice, or not a plain name.
  void finish();

  static bool present(const YAML::Node& value) { return value && !value.IsNull(); }
  static std::filesystem::path resolve(const std::string& text, const std::filesystem::path& base);

 private:
  template <typename Value>
  bool read_scalar(const std::string& key, Value& field, const std::string& expected) {
    const YAML::Node value = child(key);
    if (!present(value)) return false;
    return read_value(value, prefix_ + key, field, expected);
  }

  YAML::Node node_;
  std::string prefix_;
  std::vector<std::string>& problems_;
  std::set<std::string> known_;
  bool valid_ = true;
};

}  // namespace concord::config
