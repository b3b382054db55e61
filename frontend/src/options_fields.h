#pragma once
/// \file
/// Private to the front-end: every field of FrontendOptions with its section and key, in one
/// place, so the YAML reader, the YAML writer and frontend.json cannot disagree.

#include "concord/frontend/frontend_options.h"

namespace concord::frontend {

/// Calls visit(section, key, field) for every field; Options is FrontendOptions, const or not.
template <typename Options, typename Visitor>
void visit_option_fields(Options& options, Visitor&& visit) {
  auto& t = options.tracker;
  visit("tracker", "target_features", t.target_features);
  visit("tracker", "grid_columns", t.grid_columns);
  visit("tracker", "grid_rows", t.grid_rows);
  visit("tracker", "fast_threshold", t.fast_threshold);
  visit("tracker", "min_feature_distance", t.min_feature_distance);
  visit("tracker", "border", t.border);
  visit("tracker", "klt_window", t.klt_window);
  visit("tracker", "stereo_klt_window", t.stereo_klt_window);
  visit("tracker", "temporal_pyramid_levels", t.temporal_pyramid_levels);
  visit("tracker", "stereo_pyramid_levels", t.stereo_pyramid_levels);
  visit("tracker", "klt_iterations", t.klt_iterations);
  visit("tracker", "klt_epsilon", t.klt_epsilon);
  visit("tracker", "epipolar_tolerance", t.epipolar_tolerance);
  visit("tracker", "min_disparity", t.min_disparity);
  visit("tracker", "max_disparity", t.max_disparity);
  visit("tracker", "circular_tolerance", t.circular_tolerance);
  visit("tracker", "ransac_threshold", t.ransac_threshold);
  visit("tracker", "ransac_confidence", t.ransac_confidence);
  visit("tracker", "ransac_min_parallax", t.ransac_min_parallax);
  visit("tracker", "anchor_frames", t.anchor_frames);
  visit("tracker", "stereo_affine", t.stereo_affine);
  visit("tracker", "affine_window", t.affine_window);
  visit("tracker", "affine_tolerance", t.affine_tolerance);
  auto& o = options.odometry;
  visit("odometry", "pixel_sigma", o.pixel_sigma);
  visit("odometry", "ransac_threshold", o.ransac_threshold);
  visit("odometry", "ransac_iterations", o.ransac_iterations);
  visit("odometry", "ransac_confidence", o.ransac_confidence);
  visit("odometry", "min_inliers", o.min_inliers);
  visit("odometry", "min_disparity", o.min_disparity);
  visit("odometry", "refine_iterations", o.refine_iterations);
  visit("odometry", "refine_chi2_gate", o.refine_chi2_gate);
  visit("odometry", "failure_translation_sigma", o.failure_translation_sigma);
  visit("odometry", "failure_rotation_sigma", o.failure_rotation_sigma);
  auto& b = options.objects;
  visit("objects", "central_fraction", b.central_fraction);
  visit("objects", "min_region_size", b.min_region_size);
  visit("objects", "min_match_score", b.min_match_score);
  visit("objects", "max_disparity", b.max_disparity);
  visit("objects", "ambiguity_ratio", b.ambiguity_ratio);
  visit("objects", "left_right_tolerance", b.left_right_tolerance);
  visit("objects", "centre_depth_fraction", b.centre_depth_fraction);
  visit("objects", "upright", b.upright);
  visit("objects", "border", b.border);
  visit("objects", "detection_sigma", b.detection_sigma);
}

}  // namespace concord::frontend
