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

/// The centre of a detected object in the rectified left image (pixels) and its depth (metres).
struct ObjectCentre {
  double u = 0.0;
  double v = 0.0;
  double depth = 0.0;
};

/// The centre of the object whose detection is `box` (rectified left-image pixels) and whose
/// visible surface lies at `surface_depth`, under ObjectOptions' model: a box-shaped object as
/// deep as centre_depth_fraction makes it, its near face at surface_depth, seen as its silhouette.
/// Along the image's x axis, a detection wholly to one side of the optical axis spans the near
/// face's outer edge and the far face's inner edge (the object's side shows), which gives the
/// object's width w (the detection's width at that depth when it straddles the axis) and its
/// centre's depth, surface_depth + centre_depth_fraction * w. u is the detection's middle column
/// (an object of unknown yaw shows as much of one side as of the other on average). With
/// `upright`, v follows the same model along the rows with the depth found from x (the top or
/// bottom face seen from above or below); without it, the detection's middle row.
[[nodiscard]] ObjectCentre object_centre(const Detection& box, double surface_depth,
                                         const StereoCamera& camera, const ObjectOptions& options);

/// Measures one detection whose box is in rectified left-image pixels, on a rectified pair.
[[nodiscard]] ObjectMeasurement observe_object(const Detection& box, const cv::Mat& left,
                                               const cv::Mat& right, const StereoCamera& camera,
                                               const ObjectOptions& options);

}  // namespace concord::frontend
