#include "concord/frontend/frontend_options_file.h"

#include <charconv>
#include <map>
#include <memory>
#include <type_traits>

#include "concord/config/options_file.h"
#include "concord/config/yaml_section.h"
#include "concord/frontend/sequence.h"
#include "options_fields.h"
#include "text_lines.h"

namespace concord::frontend {

namespace {

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
    root = config::load_yaml(yaml_text, source_name);
  } catch (const config::ConfigError& error) {
    throw FrontendError(error.what());
  }
  FrontendOptions options;
  std::vector<std::string> problems;
  // The project's one YAML reader: a map of sections (tracker, odometry, objects), each a map of
  // the fields options_fields.h names.
  config::YamlSection top(root, "", problems, "a map of front-end option sections");
  std::map<std::string, std::unique_ptr<config::YamlSection>> sections;
  visit_option_fields(options, [&](const char* section, const char* key, auto& field) {
    auto& reader = sections[section];
    if (!reader) {
      reader = std::make_unique<config::YamlSection>(top.child(section), std::string(section) + ".",
                                                     problems);
    }
    reader->read(key, field);
  });
  for (auto& [name, reader] : sections) reader->finish();
  top.finish();
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
    if constexpr (std::is_same_v<std::decay_t<decltype(field)>, bool>) {
      out += "  " + std::string(key) + ": " + (field ? "true" : "false") + "\n";
    } else {
      out += "  " + std::string(key) + ": " + number_text(static_cast<double>(field)) + "\n";
    }
  });
  return out;
}

}  // namespace concord::frontend
