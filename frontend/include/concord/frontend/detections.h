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
