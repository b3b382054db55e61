#include "concord/frontend/detections.h"

#include <algorithm>
#include <charconv>
#include <set>

#include "text_lines.h"

namespace concord::frontend {

namespace {

constexpr std::string_view kHeader = "frame,track_id,class,x_min,y_min,x_max,y_max";

void append_number(std::string& out, double value) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  out.append(buffer, result.ptr);
}

}  // namespace

std::optional<int> class_number(const std::string& name) {
  if (name.empty() || name.size() > 7 ||
      !std::all_of(name.begin(), name.end(), [](char c) { return c >= '0' && c <= '9'; })) {
    return std::nullopt;
  }
  const int number = std::stoi(name);
  return number <= kMaxClassNumber ? std::optional<int>(number) : std::nullopt;
}

ClassNumbering::ClassNumbering(const std::vector<std::string>& names) {
  const std::set<std::string> distinct(names.begin(), names.end());
  if (distinct.contains("")) throw FrontendError("class names: an empty class name");
  const bool numbers = std::all_of(distinct.begin(), distinct.end(),
                                   [](const std::string& name) { return class_number(name); });
  if (numbers) {
    for (const std::string& name : distinct) numbers_.push_back(*class_number(name));
    std::sort(numbers_.begin(), numbers_.end());
  } else {
    sorted_.assign(distinct.begin(), distinct.end());
  }
}

std::optional<int> ClassNumbering::number(const std::string& name) const {
  if (sorted_.empty()) {
    const std::optional<int> value = class_number(name);
    if (!value || !std::binary_search(numbers_.begin(), numbers_.end(), *value)) return std::nullopt;
    return value;
  }
  const auto it = std::lower_bound(sorted_.begin(), sorted_.end(), name);
  if (it == sorted_.end() || *it != name) return std::nullopt;
  return static_cast<int>(it - sorted_.begin());
}

void ClassNumbering::require_all(const std::vector<std::string>& names,
                                 const std::string& where) const {
  for (const std::string& name : names) {
    if (!number(name))
      throw FrontendError(where + ": class '" + name + "' is not one of the team's classes");
  }
}

std::optional<ClassNumbering> robot_class_numbering(
    const std::vector<std::vector<Detection>>& detections,
    const std::vector<std::string>& team_classes, const std::filesystem::path& file) {
  std::set<std::string> distinct;
  for (const auto& frame : detections)
    for (const Detection& detection : frame) distinct.insert(detection.class_name);
  const std::vector<std::string> detected(distinct.begin(), distinct.end());
  if (!team_classes.empty()) {
    ClassNumbering numbering(team_classes);
    numbering.require_all(detected, file.string());
    return numbering;
  }
  const bool numbers = std::all_of(detected.begin(), detected.end(),
                                   [](const std::string& name) { return class_number(name); });
  if (detected.empty() || !numbers) return std::nullopt;
  return ClassNumbering(detected);
}

std::vector<std::vector<Detection>> read_detections(const std::filesystem::path& file,
                                                    int num_frames, bool later_frames_allowed) {
  text::LineReader reader(file);
  std::string_view line;
  if (!reader.next_line(line)) text::fail_in_file(file, "empty file, expected the header");
  {
    std::string header;
    for (const std::string_view field : text::split(line, ',')) {
      header += (header.empty() ? "" : ",") + std::string(field);
    }
    if (header != kHeader) {
      reader.fail("expected the header '" + std::string(kHeader) + "', found '" +
                  std::string(line) + "'");
    }
  }
  std::vector<std::vector<Detection>> per_frame(static_cast<std::size_t>(std::max(num_frames, 0)));
  std::set<std::pair<int, LandmarkId>> seen;
  while (reader.next_line(line)) {
    const auto fields = text::split(line, ',');
    if (fields.size() != 7) {
      reader.fail("expected 7 comma-separated fields, found " + std::to_string(fields.size()));
    }
    Detection detection;
    const std::int64_t frame = reader.integer(fields[0], "frame");
    if (frame >= num_frames && frame >= 0 && later_frames_allowed) continue;
    if (frame < 0 || frame >= num_frames) {
      reader.fail("frame " + std::to_string(frame) + " is outside [0, " +
                  std::to_string(num_frames - 1) + "] (the sequence has " +
                  std::to_string(num_frames) + " frames)");
    }
    detection.frame = static_cast<int>(frame);
    detection.track_id = reader.integer(fields[1], "track_id");
    detection.class_name = std::string(fields[2]);
    detection.x_min = reader.number(fields[3], "x_min");
    detection.y_min = reader.number(fields[4], "y_min");
    detection.x_max = reader.number(fields[5], "x_max");
    detection.y_max = reader.number(fields[6], "y_max");
    if (!(detection.x_min < detection.x_max && detection.y_min < detection.y_max)) {
      reader.fail("empty box: x_min < x_max and y_min < y_max are required");
    }
    if (!seen.emplace(detection.frame, detection.track_id).second) {
      reader.fail("track_id " + std::to_string(detection.track_id) +
                  " is detected twice in frame " + std::to_string(detection.frame));
    }
    per_frame[detection.frame].push_back(std::move(detection));
  }
  return per_frame;
}

std::string format_detections(const std::vector<std::vector<Detection>>& per_frame) {
  std::string out = std::string(kHeader) + "\n";
  for (const auto& detections : per_frame) {
    for (const Detection& detection : detections) {
      out += std::to_string(detection.frame) + "," + std::to_string(detection.track_id) + "," +
             detection.class_name;
      for (const double value :
           {detection.x_min, detection.y_min, detection.x_max, detection.y_max}) {
        out += ',';
        append_number(out, value);
      }
      out += '\n';
    }
  }
  return out;
}

}  // namespace concord::frontend
