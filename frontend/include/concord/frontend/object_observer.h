#pragma once
/// \file
/// A detection box to a stereo object observation (the paper's §VI-A: box centres are the object
/// observations). The left position is the box centre; the right position is the centre moved by
/// the object's disparity, measured by matching the box's central region along the same row of
/// the rectified right image (normalized cross-correlation, sub-pixel peak). The match sees the
/// object's visible surface, so the disparity is converted to the depth of the object's centre
/// (ObjectOptions::centre_depth_fraction). A match that is ambiguous along the row or fails the
/// left-right check gives no observation. Names OpenCV types: for the front-end and its tests.

#include <opencv2/core.hpp>
#include <optional>
#include <string>

#include "concord/estimator/types.h"
#include "concord/frontend/detections.h"
#include "concord/frontend/frontend_options.h"

namespace concord::frontend {

/// Why a detection gave no observation: at the border, too small, no match above the score, a
/// match nearly as good elsewhere along the row (ambiguous), or a match that does not match back
/// to the box's region (inconsistent).
enum class ObjectSkip { kNone, kAtBorder, kTooSmall, kNoMatch, kAmbiguous, kInconsistent };

struct ObjectMeasurement {
  /// The observation (id = the detection's track id), when measured.
  std::optional<StereoObservation> observation;
  ObjectSkip skipped = ObjectSkip::kNone;
  /// Disparity of the matched surface and of the centre, pixels; match score (NCC, in [-1, 1]).
  double surface_disparity = 0.0;
  double centre_disparity = 0.0;
  double score = 0.0;
};

/// Measures one detection whose box is in rectified left-image pixels, on a rectified pair.
[[nodiscard]] ObjectMeasurement observe_object(const Detection& box, const cv::Mat& left,
                                               const cv::Mat& right, const StereoCamera& camera,
                                               const ObjectOptions& options);

}  // namespace concord::frontend
