#include "concord/web/target.h"

#include <utility>

namespace concord::web {
namespace {

/// The value of a hex digit, or -1.
int hex_value(char digit) {
  if (digit >= '0' && digit <= '9') return digit - '0';
  if (digit >= 'a' && digit <= 'f') return digit - 'a' + 10;
  if (digit >= 'A' && digit <= 'F') return digit - 'A' + 10;
  return -1;
}

}  // namespace

std::optional<std::string> percent_decode(std::string_view text, bool plus_is_space) {
  std::string decoded;
  decoded.reserve(text.size());
  for (std::size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (c == '%') {
      if (i + 2 >= text.size()) return std::nullopt;
      const int high = hex_value(text[i + 1]);
      const int low = hex_value(text[i + 2]);
      if (high < 0 || low < 0) return std::nullopt;
      decoded.push_back(static_cast<char>(high * 16 + low));
      i += 2;
    } else if (c == '+' && plus_is_space) {
      decoded.push_back(' ');
    } else {
      decoded.push_back(c);
    }
  }
  return decoded;
}

ParsedTarget parse_target(std::string_view target) {
  ParsedTarget parsed;
  if (target.empty() || target.front() != '/') {
    parsed.error = "request target must start with '/'";
    return parsed;
  }
  const std::size_t question_mark = target.find('?');
  std::optional<std::string> path = percent_decode(target.substr(0, question_mark), false);
  if (!path) {
    parsed.error = "malformed percent-encoding in path";
    return parsed;
  }
  parsed.path = std::move(*path);
  if (question_mark == std::string_view::npos) return parsed;

  std::string_view rest = target.substr(question_mark + 1);
  while (!rest.empty()) {
    const std::size_t ampersand = rest.find('&');
    const std::string_view parameter = rest.substr(0, ampersand);
    rest = ampersand == std::string_view::npos ? std::string_view() : rest.substr(ampersand + 1);
    if (parameter.empty()) continue;
    const std::size_t equals = parameter.find('=');
    std::optional<std::string> name = percent_decode(parameter.substr(0, equals), true);
    std::optional<std::string> value = equals == std::string_view::npos
                                           ? std::string()
                                           : percent_decode(parameter.substr(equals + 1), true);
    if (!name || !value) {
      parsed.error = "malformed percent-encoding in query";
      parsed.query.clear();
      return parsed;
    }
    parsed.query[std::move(*name)] = std::move(*value);
  }
  return parsed;
}

}  // namespace concord::web
