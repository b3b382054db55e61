#include "concord/config/yaml_section.h"

#include <algorithm>
#include <limits>

#include "concord/config/options_file.h"

namespace concord::config {

std::string line_of(const YAML::Node& node) {
  const YAML::Mark mark = node.Mark();
  if (mark.is_null()) return {};
  return "line " + std::to_string(mark.line + 1) + ": ";
}

std::string describe(const YAML::Node& node) {
  if (node.IsScalar()) return "'" + node.Scalar() + "'";
  if (node.IsSequence()) return "a sequence";
  if (node.IsMap()) return "a map";
  return "nothing (null)";
}

YAML::Node load_yaml(const std::string& yaml_text, const std::string& source_name) {
  try {
    return YAML::Load(yaml_text);
  } catch (const YAML::ParserException& error) {
    throw ConfigError(source_name + ":" + std::to_string(error.mark.line + 1) +
                      ": invalid YAML: " + error.msg);
  }
}

YamlSection::YamlSection(const YAML::Node& node, std::string prefix,
                         std::vector<std::string>& problems, const std::string& expected)
    : node_(node), prefix_(std::move(prefix)), problems_(problems) {
  if (present(node_) && !node_.IsMap()) {
    const std::string name = prefix_.empty() ? "(top level)" : prefix_.substr(0, prefix_.size() - 1);
    problem(node_, name, expected);
    valid_ = false;
  }
}

YAML::Node YamlSection::child(const std::string& key) {
  known_.insert(key);
  // Absent: an undefined node (`!node`), as a missing key of a map reads.
  if (!valid_ || !present(node_)) return YAML::Node(YAML::NodeType::Undefined);
  return node_[key];
}

void YamlSection::problem(const YAML::Node& value, const std::string& key,
                          const std::string& expected) {
  problems_.push_back(line_of(value) + key + " = " + describe(value) + ": expected " + expected);
}

void YamlSection::read(const std::string& key, std::filesystem::path& field,
                       const std::filesystem::path& base) {
  std::string text;
  if (read(key, text) && !text.empty()) field = resolve(text, base);
}

void YamlSection::read_port(const std::string& key, std::uint16_t& field, bool allow_zero) {
  const YAML::Node value = child(key);
  int number = field;
  if (!present(value) || !read_value(value, prefix_ + key, number, "a port")) return;
  if (number < (allow_zero ? 0 : 1) || number > 65535) {
    problem(value, prefix_ + key, std::string("a port ") + (allow_zero ? "0" : "1") + "-65535");
    return;
  }
  field = static_cast<std::uint16_t>(number);
}

void YamlSection::read_milliseconds(const std::string& key, std::chrono::milliseconds& field,
                                    bool allow_zero) {
  const YAML::Node value = child(key);
  int number = 0;
  const std::string expected =
      std::string("a ") + (allow_zero ? "non-negative" : "positive") + " number of ms";
  if (!present(value) || !read_value(value, prefix_ + key, number, expected)) return;
  if (number < 0 || (!allow_zero && number == 0)) return problem(value, prefix_ + key, expected);
  field = std::chrono::milliseconds(number);
}

void YamlSection::read_size(const std::string& key, std::size_t& field) {
  const YAML::Node value = child(key);
  int number = 0;
  if (!present(value) || !read_value(value, prefix_ + key, number, "a positive integer")) return;
  if (number < 1) return problem(value, prefix_ + key, "a positive integer");
  field = static_cast<std::size_t>(number);
}

void YamlSection::read_ints(const std::string& key, std::vector<int>& field) {
  const YAML::Node value = child(key);
  if (!present(value)) return;
  std::vector<int> numbers;
  bool valid = value.IsSequence();
  if (valid) {
    for (const auto& item : value) {
      try {
        numbers.push_back(item.as<int>());
      } catch (const YAML::Exception&) {
        valid = false;
        break;
      }
    }
  }
  if (!valid) return problem(value, prefix_ + key, "a sequence of integers");
  field = std::move(numbers);
}

void YamlSection::read_strings(const std::string& key, std::vector<std::string>& field) {
  const YAML::Node value = child(key);
  if (!present(value)) return;
  std::vector<std::string> strings;
  bool valid = value.IsSequence();
  if (valid) {
    for (const auto& item : value) {
      if (!item.IsScalar()) {
        valid = false;
        break;
      }
      strings.push_back(item.Scalar());
    }
  }
  if (!valid) return problem(value, prefix_ + key, "a sequence of strings");
  field = std::move(strings);
}

void YamlSection::read_numbers(const std::string& key, std::vector<double>& field,
                               std::size_t count) {
  const YAML::Node value = child(key);
  if (!present(value)) return;
  std::vector<double> numbers;
  if (value.IsSequence() && value.size() == count) {
    for (const auto& item : value) {
      try {
        numbers.push_back(item.as<double>());
      } catch (const YAML::Exception&) {
        break;
      }
    }
  }
  if (numbers.size() != count)
    return problem(value, prefix_ + key, "a sequence of " + std::to_string(count) + " numbers");
  field = std::move(numbers);
}

void YamlSection::finish() {
  if (!valid_ || !present(node_)) return;
  std::set<std::string> seen;
  for (const auto& entry : node_) {
    if (!entry.first.IsScalar()) {
      problems_.push_back(line_of(entry.first) + "key " + prefix_ + describe(entry.first) +
                          " is not a plain name");
      continue;
    }
    const std::string key = entry.first.Scalar();
    if (!seen.insert(key).second) {
      problems_.push_back(line_of(entry.first) + "key " + prefix_ + key + " appears more than once");
    } else if (!known_.count(key)) {
      problems_.push_back(line_of(entry.first) + "unknown key " + prefix_ + key);
    }
  }
}

std::filesystem::path YamlSection::resolve(const std::string& text,
                                           const std::filesystem::path& base) {
  const std::filesystem::path path(text);
  return path.is_absolute() || base.empty() ? path : (base / path).lexically_normal();
}

}  // namespace concord::config
