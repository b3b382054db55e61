#pragma once
/// \file
/// Private to the dataset library: the one place that reads and writes the plain-text formats of
/// the dataset and result folders (KITTI pose lines, comma-separated tables, numbers). Errors are
/// DatasetError with "<file>:<line>: <problem>" messages. Parsing walks a file read whole with
/// std::from_chars (no stream per token): the largest shared file has 52k rows.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <iterator>
#include <span>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

#include "concord/dataset/dataset.h"
#include "concord/estimator/lie.h"

namespace concord::dataset::text_parsing {

/// Largest |R^T R - I| entry accepted for a rotation block read from a file.
inline constexpr double kRotationTolerance = 1e-3;
/// Rotation blocks further than this from orthonormal are replaced by the nearest rotation;
/// closer ones are kept bit for bit (so a written and re-read pose is unchanged).
inline constexpr double kOrthonormalizeAbove = 1e-12;

/// The pieces joined into one string.
inline std::string concatenate(std::initializer_list<std::string_view> pieces) {
  std::string text;
  for (const std::string_view piece : pieces) text += piece;
  return text;
}

/// `token` without one leading '+' (std::from_chars does not accept it).
inline std::string_view without_plus_sign(std::string_view token) {
  if (token.size() > 1 && token.front() == '+') token.remove_prefix(1);
  return token;
}

/// Throws DatasetError "<file>: <problem>".
[[noreturn]] inline void fail_in_file(const std::filesystem::path& file, std::string_view problem) {
  throw DatasetError(concatenate({file.string(), ": ", problem}));
}

/// Throws DatasetError "<file>:<line>: <problem>".
[[noreturn]] inline void fail_at_line(const std::filesystem::path& file, int line,
                                      std::string_view problem) {
  throw DatasetError(concatenate({file.string(), ":", std::to_string(line), ": ", problem}));
}

/// The whole content of a file; DatasetError if it is missing or unreadable.
inline std::string read_whole_file(const std::filesystem::path& file) {
  std::error_code error;
  const auto status = std::filesystem::status(file, error);
  if (!std::filesystem::exists(status)) fail_in_file(file, "file not found");
  if (!std::filesystem::is_regular_file(status)) fail_in_file(file, "not a regular file");
  std::ifstream stream(file, std::ios::binary);
  if (!stream) fail_in_file(file, "cannot open file");
  std::string content((std::istreambuf_iterator<char>(stream)), std::istreambuf_iterator<char>());
  if (stream.bad()) fail_in_file(file, "read error");
  return content;
}

/// `text` without leading and trailing spaces, tabs and carriage returns.
inline std::string_view trimmed(std::string_view text) {
  constexpr std::string_view kBlanks = " \t\r";
  const auto first = text.find_first_not_of(kBlanks);
  if (first == std::string_view::npos) return {};
  const auto last = text.find_last_not_of(kBlanks);
  return text.substr(first, last - first + 1);
}

/// Shortest text that reads back as exactly `value` (at most 17 significant digits).
inline void append_number(std::string& out, double value) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  out.append(buffer, result.ptr);
}

inline void append_integer(std::string& out, std::int64_t value) {
  char buffer[24];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  out.append(buffer, result.ptr);
}

/// Checks that the rotation block of `pose` is a rotation within kRotationTolerance and makes it
/// exactly orthonormal if it is not already. Returns the problem, or an empty string if none.
inline std::string check_and_orthonormalize_rotation(Eigen::Isometry3d& pose) {
  const Eigen::Matrix3d rotation = pose.linear();
  const double orthonormality_error =
      (rotation.transpose() * rotation - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (!(orthonormality_error <= kRotationTolerance)) {
    std::string problem = "rotation block is not a rotation (largest |R^T R - I| entry is ";
    append_number(problem, orthonormality_error);
    problem += ", tolerance ";
    append_number(problem, kRotationTolerance);
    return problem + ")";
  }
  if (rotation.determinant() < 0.0) return "rotation block is a reflection (determinant < 0)";
  if (orthonormality_error > kOrthonormalizeAbove) pose = lie::orthonormalized(pose);
  return {};
}

/// A text file read whole and walked line by line; errors name the file and the current line.
/// Blank lines at the end of the file are ignored; blank lines elsewhere are handed out (and
/// rejected by the format's own checks).
class TextFile {
 public:
  explicit TextFile(std::filesystem::path file)
      : file_(std::move(file)), content_(read_whole_file(file_)) {
    const auto last_character = content_.find_last_not_of(" \t\r\n");
    if (last_character != std::string::npos) {
      remaining_ = std::string_view(content_).substr(0, last_character + 1);
      has_more_ = true;
    }
  }

  // Not copyable or movable: the position in the file is a view into content_.
  TextFile(const TextFile&) = delete;
  TextFile& operator=(const TextFile&) = delete;

  const std::filesystem::path& path() const { return file_; }
  /// 1-based number of the line last returned by next_line (0 before the first).
  int line_number() const { return line_number_; }

  /// The next line without its line break; false at the end.
  bool next_line(std::string_view& line) {
    if (!has_more_) return false;
    const auto newline = remaining_.find('\n');
    if (newline == std::string_view::npos) {
      line = remaining_;
      has_more_ = false;
    } else {
      line = remaining_.substr(0, newline);
      remaining_.remove_prefix(newline + 1);
    }
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    ++line_number_;
    return true;
  }

  /// Throws DatasetError naming the file and the current line.
  [[noreturn]] void fail(std::string_view problem) const {
    fail_at_line(file_, line_number_, problem);
  }

  /// `token` as a finite double; `name` names the value in the error.
  double parse_double(std::string_view token, std::string_view name) const {
    std::string_view digits = without_plus_sign(token);
    double value = 0.0;
    const auto result = std::from_chars(digits.data(), digits.data() + digits.size(), value);
    if (result.ec == std::errc::result_out_of_range) {
      fail(concatenate({name, " '", token, "' is out of the range of a double"}));
    }
    if (digits.empty() || result.ec != std::errc() || result.ptr != digits.data() + digits.size()) {
      fail(concatenate({name, " '", token, "' is not a number"}));
    }
    if (!std::isfinite(value)) fail(concatenate({name, " '", token, "' is not finite"}));
    return value;
  }

  /// `token` as an integer; `name` names the value in the error.
  std::int64_t parse_integer(std::string_view token, std::string_view name) const {
    std::string_view digits = without_plus_sign(token);
    std::int64_t value = 0;
    const auto result = std::from_chars(digits.data(), digits.data() + digits.size(), value);
    if (result.ec == std::errc::result_out_of_range) {
      fail(concatenate({name, " '", token, "' is out of range"}));
    }
    if (digits.empty() || result.ec != std::errc() || result.ptr != digits.data() + digits.size()) {
      fail(concatenate({name, " '", token, "' is not an integer"}));
    }
    return value;
  }

 private:
  std::filesystem::path file_;
  std::string content_;
  std::string_view remaining_;
  bool has_more_ = false;
  int line_number_ = 0;
};

/// Names of the 12 numbers of a KITTI line in error messages.
inline constexpr std::array<std::string_view, 12> kKittiEntryNames{
    "entry 1", "entry 2", "entry 3", "entry 4",  "entry 5",  "entry 6",
    "entry 7", "entry 8", "entry 9", "entry 10", "entry 11", "entry 12"};

/// Reads a KITTI pose file: one pose per line, the top 3x4 block of the 4x4 matrix, row-major,
/// 12 numbers separated by blanks.
inline std::vector<Eigen::Isometry3d> read_kitti_poses(const std::filesystem::path& file) {
  TextFile text(file);
  std::vector<Eigen::Isometry3d> poses;
  std::string_view line;
  while (text.next_line(line)) {
    std::string_view tokens[12];
    int count = 0;
    std::size_t position = 0;
    while (true) {
      position = line.find_first_not_of(" \t", position);
      if (position == std::string_view::npos) break;
      const auto end = std::min(line.find_first_of(" \t", position), line.size());
      if (count < 12) tokens[count] = line.substr(position, end - position);
      ++count;
      position = end;
    }
    if (count != 12) {
      text.fail("expected 12 numbers (a 3x4 pose, row-major), found " + std::to_string(count));
    }
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    for (int index = 0; index < 12; ++index) {
      pose.matrix()(index / 4, index % 4) =
          text.parse_double(tokens[index], kKittiEntryNames[index]);
    }
    const std::string problem = check_and_orthonormalize_rotation(pose);
    if (!problem.empty()) text.fail(problem);
    poses.push_back(pose);
  }
  return poses;
}

/// The text of a KITTI pose file (see read_kitti_poses), numbers in their shortest exact form.
inline std::string format_kitti_poses(const std::vector<Eigen::Isometry3d>& poses) {
  std::string out;
  out.reserve(poses.size() * 12 * 24);
  for (const Eigen::Isometry3d& pose : poses) {
    for (int index = 0; index < 12; ++index) {
      if (index > 0) out += ' ';
      append_number(out, pose.matrix()(index / 4, index % 4));
    }
    out += '\n';
  }
  return out;
}

/// The header line of a CSV table with the given column names, without a line break.
inline std::string csv_header(std::span<const std::string_view> columns) {
  std::string header;
  for (std::size_t index = 0; index < columns.size(); ++index) {
    if (index > 0) header += ',';
    header += columns[index];
  }
  return header;
}

/// Reads a comma-separated table whose first line must be exactly the expected header (fields
/// are trimmed of blanks), or the expected header followed by the optional trailing columns (all
/// of them, in order). Each row must have as many fields as the header. The column names must
/// outlive the reader.
class CsvReader {
 public:
  CsvReader(std::filesystem::path file, std::span<const std::string_view> columns,
            std::span<const std::string_view> optional_columns = {})
      : text_(std::move(file)), columns_(columns.begin(), columns.end()) {
    fields_.reserve(columns_.size() + optional_columns.size());
    const std::string expected = csv_header(columns);
    std::vector<std::string_view> with_optional = columns_;
    with_optional.insert(with_optional.end(), optional_columns.begin(), optional_columns.end());
    const std::string expected_with_optional = csv_header(with_optional);
    std::string_view line;
    if (!text_.next_line(line)) {
      fail_in_file(text_.path(), "empty file, expected the header '" + expected + "'");
    }
    split(line);
    const auto header_is = [&](const std::vector<std::string_view>& names) {
      if (fields_.size() != names.size()) return false;
      for (std::size_t index = 0; index < fields_.size(); ++index) {
        if (fields_[index] != names[index]) return false;
      }
      return true;
    };
    if (!optional_columns.empty() && header_is(with_optional)) {
      columns_ = std::move(with_optional);
      has_optional_columns_ = true;
    } else if (!header_is(columns_)) {
      text_.fail("expected the header '" + expected + "', found '" + std::string(line) + "'" +
                 (optional_columns.empty()
                      ? std::string()
                      : " (or with optional columns: '" + expected_with_optional + "')"));
    }
  }

  /// Whether the header carried the optional trailing columns.
  bool has_optional_columns() const { return has_optional_columns_; }

  /// Moves to the next row; false at the end. Throws on a wrong number of fields.
  bool next_row() {
    std::string_view line;
    if (!text_.next_line(line)) return false;
    split(line);
    if (fields_.size() != columns_.size()) {
      text_.fail("expected " + std::to_string(columns_.size()) + " comma-separated fields, found " +
                 std::to_string(fields_.size()));
    }
    return true;
  }

  /// Field `column` of the current row as a finite double.
  double number(std::size_t column) const {
    return text_.parse_double(fields_[column], columns_[column]);
  }

  /// Field `column` of the current row as an integer.
  std::int64_t integer(std::size_t column) const {
    return text_.parse_integer(fields_[column], columns_[column]);
  }

  /// Throws DatasetError naming the file and the current line.
  [[noreturn]] void fail(std::string_view problem) const { text_.fail(problem); }

 private:
  void split(std::string_view line) {
    fields_.clear();
    std::size_t start = 0;
    while (true) {
      const auto comma = line.find(',', start);
      if (comma == std::string_view::npos) {
        fields_.push_back(trimmed(line.substr(start)));
        return;
      }
      fields_.push_back(trimmed(line.substr(start, comma - start)));
      start = comma + 1;
    }
  }

  TextFile text_;
  std::vector<std::string_view> columns_;
  std::vector<std::string_view> fields_;
  bool has_optional_columns_ = false;
};

}  // namespace concord::dataset::text_parsing
