#pragma once
/// \file
/// Pure parsing of an HTTP request target ("/path?name=value&..."), with percent-decoding. No
/// sockets: the server calls it, tests call it directly.

#include <map>
#include <optional>
#include <string>
#include <string_view>

namespace concord::web {

/// A request target split into its decoded path and query, or why it is malformed.
struct ParsedTarget {
  /// Percent-decoded path ('+' stays '+').
  std::string path;
  /// Percent-decoded query parameters ('+' decodes to a space); a parameter without '=' maps to
  /// ""; empty parameters ("a=1&&b=2") are skipped; when a name repeats the last value wins.
  std::map<std::string, std::string> query;
  /// Empty when the target is well formed, otherwise what is wrong with it.
  std::string error;

  bool ok() const { return error.empty(); }
};

/// Parses an origin-form target: it must start with '/'; a '%' must be followed by two hex
/// digits.
ParsedTarget parse_target(std::string_view target);

/// Decodes "%XX" escapes (and '+' as a space when `plus_is_space`); std::nullopt when a '%' is
/// not followed by two hex digits.
std::optional<std::string> percent_decode(std::string_view text, bool plus_is_space);

}  // namespace concord::web
