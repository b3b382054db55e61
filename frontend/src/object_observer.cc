#include "concord/frontend/object_observer.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "concord/frontend/sequence.h"
#include "row_search.h"
#include "text_lines.h"

namespace concord::frontend {

std::vector<std::string> ObjectOptions::validate() const {
  std::vector<std::string> problems;
  const auto require = [&](bool ok, const std::string& field, double value, const char* rule) {
    if (!ok) problems.push_back(text::problem(field, value, rule));
  };
  require(central_fraction > 0.0 && central_fraction <= 1.0, "central_fraction", central_fraction,
          "in (0, 1]");
  require(min_region_size >= 3, "min_region_size", min_region_size, ">= 3");
  require(min_match_score > -1.0 && min_match_score < 1.0, "min_match_score", min_match_score,
          "in (-1, 1)");
  require(max_disparity > 0.0, "max_disparity", max_disparity, "> 0");
  require(ambiguity_ratio > 0.0 && ambiguity_ratio <= 1.0, "ambiguity_ratio", ambiguity_ratio,
          "in (0, 1]");
  require(left_right_tolerance >= 0.0, "left_right_tolerance", left_right_tolerance, ">= 0");
  require(centre_depth_fraction >= 0.0, "centre_depth_fraction", centre_depth_fraction, ">= 0");
  require(border >= 0, "border", border, ">= 0");
  require(detection_sigma > 0.0, "detection_sigma", detection_sigma, "> 0");
  return problems;
}

namespace {

/// One image axis of the silhouette model: the extent (centre X and size w, metres, in the
/// camera frame) of a box-shaped object whose near face is at depth `near` and whose depth is
/// depth + depth_per_width * w, from its silhouette's edges `low` < `high` (normalized image
/// coordinates along the axis). A silhouette wholly on one side of the optical axis spans the
/// near face's outer edge and the far face's inner edge; one that straddles the axis spans the
/// near face.
struct AxisExtent {
  double centre = 0.0;
  double size = 0.0;
};

AxisExtent silhouette_extent(double low, double high, double near, double depth,
                             double depth_per_width) {
  const AxisExtent straddling{0.5 * (low + high) * near, (high - low) * near};
  if (low > 0.0) {
    // centre + w/2 = high * near; centre - w/2 = low * (near + depth + depth_per_width * w).
    const double size = ((high - low) * near - low * depth) / (1.0 + low * depth_per_width);
    if (!(size > 0.0)) return straddling;
    return {high * near - 0.5 * size, size};
  }
  if (high < 0.0) {
    // centre - w/2 = low * near; centre + w/2 = high * (near + depth + depth_per_width * w).
    const double size = ((high - low) * near + high * depth) / (1.0 - high * depth_per_width);
    if (!(size > 0.0)) return straddling;
    return {low * near + 0.5 * size, size};
  }
  return straddling;
}

}  // namespace

ObjectCentre object_centre(const Detection& box, double surface_depth, const StereoCamera& camera,
                           const ObjectOptions& options) {
  const double fx = camera.K(0, 0), fy = camera.K(1, 1);
  const double cx = camera.K(0, 2), cy = camera.K(1, 2);
  const double depth_per_width = 2.0 * options.centre_depth_fraction;
  const AxisExtent across = silhouette_extent((box.x_min - cx) / fx, (box.x_max - cx) / fx,
                                              surface_depth, 0.0, depth_per_width);
  const double object_depth = depth_per_width * across.size;
  ObjectCentre centre;
  centre.depth = surface_depth + 0.5 * object_depth;
  centre.u = box.centre_x();
  centre.v = box.centre_y();
  if (options.upright) {
    const AxisExtent up = silhouette_extent((box.y_min - cy) / fy, (box.y_max - cy) / fy,
                                            surface_depth, object_depth, 0.0);
    centre.v = cy + fy * up.centre / centre.depth;
  }
  return centre;
}

ObjectMeasurement observe_object(const Detection& box, const cv::Mat& left, const cv::Mat& right,
                                 const StereoCamera& camera, const ObjectOptions& options) {
  ObjectMeasurement result;
  const double border = options.border;
  if (box.x_min < border || box.y_min < border || box.x_max > left.cols - 1 - border ||
      box.y_max > left.rows - 1 - border) {
    result.skipped = ObjectSkip::kAtBorder;
    return result;
  }
  // 1. The central region of the box in the left image.
  const double centre_x = box.centre_x(), centre_y = box.centre_y();
  const int width =
      static_cast<int>(std::round((box.x_max - box.x_min) * options.central_fraction));
  const int height =
      static_cast<int>(std::round((box.y_max - box.y_min) * options.central_fraction));
  if (width < options.min_region_size || height < options.min_region_size) {
    result.skipped = ObjectSkip::kTooSmall;
    return result;
  }
  const cv::Rect region(static_cast<int>(std::round(centre_x - 0.5 * width)),
                        static_cast<int>(std::round(centre_y - 0.5 * height)), width, height);
  // 2. Its match along the same rows of the right image, disparities 0 to max_disparity (at most
  //    the image width, which also keeps any configured value within int).
  const int max_disparity =
      static_cast<int>(std::min(options.max_disparity, static_cast<double>(left.cols)));
  const int search_start = std::max(0, region.x - max_disparity);
  const cv::Rect strip(search_start, region.y, region.x + region.width - search_start,
                       region.height);
  const int exclusion = std::max(2, region.width / 2);
  const RowMatch match = match_along_row(right(strip), left(region), exclusion);
  result.score = match.score;
  if (!(match.score >= options.min_match_score)) {
    result.skipped = ObjectSkip::kNoMatch;
    return result;
  }
  // 3. Checks of the match: no other peak along the row nearly as good (a repeated or weak
  //    texture), and the matched right region matches back to the box's region (left-right
  //    consistency; a region partly covered by another surface fails it).
  if (match.score > 0.0 && match.second >= options.ambiguity_ratio * match.score) {
    result.skipped = ObjectSkip::kAmbiguous;
    return result;
  }
  const int right_x = search_start + match.x;
  const int back_end = std::min(left.cols, right_x + region.width + max_disparity);
  const cv::Rect back_strip(right_x, region.y, back_end - right_x, region.height);
  const RowMatch back =
      match_along_row(left(back_strip),
                      right(cv::Rect(right_x, region.y, region.width, region.height)), exclusion);
  if (std::abs(right_x + back.x - region.x) > options.left_right_tolerance) {
    result.skipped = ObjectSkip::kInconsistent;
    return result;
  }
  // Sub-pixel peak: a parabola through the best score and its neighbours.
  double offset = 0.0;
  if (std::isfinite(match.before) && std::isfinite(match.after)) {
    const double curvature = match.before - 2.0 * match.score + match.after;
    if (curvature < 0.0) {
      offset = std::clamp(0.5 * (match.before - match.after) / curvature, -0.5, 0.5);
    }
  }
  const double surface_disparity = region.x - (search_start + match.x + offset);
  if (!(surface_disparity > 0.0)) {
    result.skipped = ObjectSkip::kNoMatch;
    return result;
  }
  // 4. From the surface to the object's centre (object_centre's silhouette model).
  const double focal_baseline = camera.K(0, 0) * camera.baseline();
  const ObjectCentre centre =
      object_centre(box, focal_baseline / surface_disparity, camera, options);
  result.surface_disparity = surface_disparity;
  result.centre_disparity = focal_baseline / centre.depth;
  StereoObservation observation;
  observation.id = box.track_id;
  observation.uv = Eigen::Vector4d(centre.u, centre.v, centre.u - result.centre_disparity, centre.v);
  result.observation = observation;
  return result;
}

}  // namespace concord::frontend
