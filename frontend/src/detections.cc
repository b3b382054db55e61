#include "concord/frontend/detections.h"

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
