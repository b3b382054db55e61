#pragma once
/// \file
/// Object detections as the robot's own detector and tracker give them, one table per sequence:
///
///     frame,track_id,class,x_min,y_min,x_max,y_max
///
/// with the box in left-image pixels (the input image as stored: raw for EuRoC, rectified for
/// KITTI) and track_id the object's id (the same id is the same object, for every robot). The
/// front-end turns each box into a stereo object observation (ObjectObserver). OpenCV-free.

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "concord/estimator/types.h"

namespace concord::frontend {

/// One detected box.
struct Detection {
  int frame = 0;
  LandmarkId track_id = 0;
  /// The detector's class name (not used by the estimator; kept for the reader).
  std::string class_name;
  double x_min = 0.0, y_min = 0.0, x_max = 0.0, y_max = 0.0;

  double centre_x() const { return 0.5 * (x_min + x_max); }
  double centre_y() const { return 0.5 * (y_min + y_max); }
};

/// Class names that are numbers are taken as those numbers up to this one.
inline constexpr int kMaxClassNumber = 1000000;

/// How a team's detector class names become the class numbers the negotiated association compares
/// (objects.csv's class column, SensorFrame.object_classes, the daemons' tallies). When every name
/// is a number (0 to kMaxClassNumber) the numbers are the names; otherwise the distinct names are
/// numbered 0, 1, ... in sorted order. The numbers depend only on the set of names, so robots
/// that are given the same names (in any order) number them alike.
class ClassNumbering {
 public:
  /// The numbering of `names` (duplicates allowed). Throws FrontendError on an empty name.
  explicit ClassNumbering(const std::vector<std::string>& names);

  /// The number of `name`, or nullopt when it is not one of the names.
  [[nodiscard]] std::optional<int> number(const std::string& name) const;
  /// Throws FrontendError, starting with `where`, for the first of `names` that is not one of
  /// the names.
  void require_all(const std::vector<std::string>& names, const std::string& where) const;
  /// The distinct names in number order when they are numbered by position; empty when the names
  /// are numbers.
  [[nodiscard]] const std::vector<std::string>& numbered_names() const { return sorted_; }

 private:
  std::vector<std::string> sorted_;
  std::vector<int> numbers_;  ///< the names as numbers, sorted (when every name is one)
};

/// How one robot's detections are numbered when the robot cannot see the team's other detections
/// (a daemon's image source): by `team_classes` when given, the team's list, the same on every
/// robot (throws FrontendError naming `file` and the class for a detected class not in it); else
/// by the detected names themselves when they are all numbers; else nullopt: names alone are not
/// numbered alike by robots that detect different sets of them.
[[nodiscard]] std::optional<ClassNumbering> robot_class_numbering(
    const std::vector<std::vector<Detection>>& detections,
    const std::vector<std::string>& team_classes, const std::filesystem::path& file);

/// A class name that is a number from 0 to kMaxClassNumber, as that number.
[[nodiscard]] std::optional<int> class_number(const std::string& name);

/// Reads a detections table into one list per frame (num_frames lists). Throws FrontendError
/// naming the file and line on a wrong header, a malformed number, a negative frame or one at or
/// after num_frames (unless later_frames_allowed: a sequence cut short, whose later detections
/// are dropped), an empty box (x_min >= x_max or y_min >= y_max) or a track id detected twice in
/// one frame.
[[nodiscard]] std::vector<std::vector<Detection>> read_detections(
    const std::filesystem::path& file, int num_frames, bool later_frames_allowed = false);

/// The text of a detections table (header and one row per detection, frames in order).
std::string format_detections(const std::vector<std::vector<Detection>>& per_frame);

}  // namespace concord::frontend
