#include "concord/frontend/frontend_options_file.h"

#include <yaml-cpp/yaml.h>

#include <charconv>
#include <set>
#include <type_traits>

#include "concord/frontend/sequence.h"
#include "options_fields.h"
#include "text_lines.h"

namespace concord::frontend {

namespace {

std::string line_of(const YAML::Node& node) {
  const YAML::Mark mark = node.Mark();
  return mark.is_null() ? std::string() : "line " + std::to_string(mark.line + 1) + ": ";
}

std::string number_text(double value) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  return std::string(buffer, result.ptr);
}

}  // namespace

FrontendOptions parse_frontend_options(const std::string& yaml_text,
                                       const std::string& source_name) {
  YAML::Node root;
  try {
    root = YAML::Load(yaml_text);
  } catch (const YAML::ParserException& error) {
    throw FrontendError(source_name + ":" + std::to_string(error.mark.line + 1) +
                        ": invalid YAML: " + error.msg);
  }
  FrontendOptions options;
  std::vector<std::string> problems;
  if (!root || root.IsNull()) return options;
  if (!root.IsMap()) throw FrontendError(source_name + ": expected a map of front-end options");

  std::set<std::string> known_sections, known_keys;
  visit_option_fields(options, [&](const char* section, const char* key, auto& field) {
    known_sections.insert(section);
    known_keys.insert(std::string(section) + "." + key);
    const YAML::Node map = root[section];
    if (!map || !map.IsMap()) return;
    const YAML::Node value = map[key];
    if (!value || value.IsNull()) return;
    using Field = std::remove_reference_t<decltype(field)>;
    try {
      if (!value.IsScalar()) throw YAML::Exception(value.Mark(), "not a scalar");
      field = value.as<Field>();
    } catch (const YAML::Exception&) {
      problems.push_back(line_of(value) + section + "." + key + ": expected " +
                         (std::is_integral_v<Field> ? "an integer" : "a number"));
    }
  });
  for (const auto& section : root) {
    const std::string name = section.first.as<std::string>("?");
    if (!known_sections.count(name)) {
      problems.push_back(line_of(section.first) + "unknown section '" + name +
                         "' (expected tracker, odometry or objects)");
      continue;
    }
    if (!section.second.IsMap()) {
      if (!section.second.IsNull())
        problems.push_back(line_of(section.second) + name + ": expected a map");
      continue;
    }
    for (const auto& entry : section.second) {
      const std::string key = name + "." + entry.first.as<std::string>("?");
      if (!known_keys.count(key)) problems.push_back(line_of(entry.first) + "unknown key " + key);
    }
  }
  if (problems.empty()) problems = options.validate();
  if (!problems.empty()) {
    std::string message = source_name + ": invalid front-end options:";
    for (const std::string& problem : problems) message += "\n  " + problem;
    throw FrontendError(message);
  }
  return options;
}

FrontendOptions load_frontend_options(const std::filesystem::path& file) {
  return parse_frontend_options(text::read_text(file), file.string());
}

std::string to_yaml(const FrontendOptions& options) {
  std::string out;
  std::string current;
  visit_option_fields(options, [&](const char* section, const char* key, const auto& field) {
    if (current != section) {
      out += std::string(section) + ":\n";
      current = section;
    }
    out += "  " + std::string(key) + ": " + number_text(static_cast<double>(field)) + "\n";
  });
  return out;
}

}  // namespace concord::frontend
