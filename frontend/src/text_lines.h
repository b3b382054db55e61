#pragma once
/// \file
/// Private to the front-end: a text file walked line by line, with numbers parsed strictly and
/// errors that name the file and line ("<file>:<line>: <problem>", as FrontendError). Used for
/// EuRoC's data.csv files, KITTI's calib.txt and times.txt and detections.csv.

#include <charconv>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include "concord/frontend/sequence.h"

namespace concord::frontend::text {

/// Throws FrontendError "<file>: <problem>".
[[noreturn]] inline void fail_in_file(const std::filesystem::path& file, std::string_view problem) {
  throw FrontendError(file.string() + ": " + std::string(problem));
}

/// A number in its shortest exact form ("4", "0.25"), for messages.
inline std::string number_text(double value) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  return std::string(buffer, result.ptr);
}

/// A validation problem: "<field> = <value>: must be <rule>".
inline std::string problem(const std::string& field, double value, const char* rule) {
  return field + " = " + number_text(value) + ": must be " + rule;
}

/// `text` without leading and trailing blanks (spaces, tabs, carriage returns).
inline std::string_view trimmed(std::string_view text) {
  constexpr std::string_view kBlanks = " \t\r";
  const auto first = text.find_first_not_of(kBlanks);
  if (first == std::string_view::npos) return {};
  return text.substr(first, text.find_last_not_of(kBlanks) - first + 1);
}

/// Fields of `line` separated by `separator` (trimmed), or by runs of blanks when separator is
/// ' '.
inline std::vector<std::string_view> split(std::string_view line, char separator) {
  std::vector<std::string_view> fields;
  if (separator == ' ') {
    std::size_t position = 0;
    while ((position = line.find_first_not_of(" \t\r", position)) != std::string_view::npos) {
      const auto end = std::min(line.find_first_of(" \t\r", position), line.size());
      fields.push_back(line.substr(position, end - position));
      position = end;
    }
    return fields;
  }
  std::size_t start = 0;
  while (true) {
    const auto next = line.find(separator, start);
    fields.push_back(
        trimmed(line.substr(start, next == std::string_view::npos ? next : next - start)));
    if (next == std::string_view::npos) return fields;
    start = next + 1;
  }
}

/// The whole content of a text file; FrontendError if it is missing or unreadable.
inline std::string read_text(const std::filesystem::path& file) {
  std::error_code error;
  if (!std::filesystem::is_regular_file(file, error)) fail_in_file(file, "file not found");
  std::ifstream stream(file, std::ios::binary);
  if (!stream) fail_in_file(file, "cannot open file");
  return std::string(std::istreambuf_iterator<char>(stream), std::istreambuf_iterator<char>());
}

/// A whole text file handed out line by line. Blank lines are skipped.
class LineReader {
 public:
  explicit LineReader(std::filesystem::path file)
      : file_(std::move(file)), content_(read_text(file_)), remaining_(content_) {}
  LineReader(const LineReader&) = delete;
  LineReader& operator=(const LineReader&) = delete;

  const std::filesystem::path& path() const { return file_; }
  int line_number() const { return line_number_; }

  /// The next non-blank line (without its line break); false at the end.
  bool next_line(std::string_view& line) {
    while (!remaining_.empty()) {
      const auto newline = remaining_.find('\n');
      line = remaining_.substr(0, newline);
      remaining_.remove_prefix(newline == std::string_view::npos ? remaining_.size() : newline + 1);
      ++line_number_;
      if (!trimmed(line).empty()) {
        if (line.back() == '\r') line.remove_suffix(1);
        return true;
      }
    }
    return false;
  }

  /// Throws FrontendError naming the file and the current line.
  [[noreturn]] void fail(std::string_view problem) const {
    throw FrontendError(file_.string() + ":" + std::to_string(line_number_) + ": " +
                        std::string(problem));
  }

  /// `token` as a finite double; `name` names the value in the error.
  double number(std::string_view token, std::string_view name) const {
    if (token.size() > 1 && token.front() == '+') token.remove_prefix(1);
    double value = 0.0;
    const auto result = std::from_chars(token.data(), token.data() + token.size(), value);
    if (token.empty() || result.ec != std::errc() || result.ptr != token.data() + token.size() ||
        !std::isfinite(value)) {
      fail(std::string(name) + " '" + std::string(token) + "' is not a finite number");
    }
    return value;
  }

  /// `token` as an integer; `name` names the value in the error.
  std::int64_t integer(std::string_view token, std::string_view name) const {
    if (token.size() > 1 && token.front() == '+') token.remove_prefix(1);
    std::int64_t value = 0;
    const auto result = std::from_chars(token.data(), token.data() + token.size(), value);
    if (token.empty() || result.ec != std::errc() || result.ptr != token.data() + token.size()) {
      fail(std::string(name) + " '" + std::string(token) + "' is not an integer");
    }
    return value;
  }

 private:
  std::filesystem::path file_;
  std::string content_;
  std::string_view remaining_;
  int line_number_ = 0;
};

}  // namespace concord::frontend::text
