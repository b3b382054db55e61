#pragma once
/// \file
/// Every tunable of the stereo front-end, with defaults in-class (docs/frontend.md explains each
/// and why). Pixel values are in rectified image pixels. OpenCV-free.

#include <string>
#include <vector>

namespace concord::frontend {

/// Feature detection and tracking (StereoTracker).
struct TrackerOptions {
  /// Tracks kept per frame: new FAST corners are added while fewer are tracked.
  int target_features = 200;
  /// The left image is cut into grid_columns x grid_rows cells; each cell gets an equal share of
  /// the target, so features spread over the image.
  int grid_columns = 8;
  int grid_rows = 5;
  /// FAST intensity threshold (corners are then ranked by their FAST score).
  int fast_threshold = 10;
  /// Smallest distance between two tracked features, pixels.
  double min_feature_distance = 8.0;
  /// Features closer than this to the image border are dropped, pixels.
  int border = 8;
  /// Pyramidal KLT: window side (pixels, odd) for temporal tracking (a small window follows a
  /// surface with less bias as its appearance changes) and for stereo matching (left to right,
  /// where more texture matters more), pyramid levels above the image for temporal tracking and
  /// for the stereo tracking of continued tracks, which starts from the track's previous
  /// disparity; iterations and convergence threshold. New features start from a coarse search
  /// along the row (half resolution) and are refined on one level.
  int klt_window = 11;
  int stereo_klt_window = 21;
  int temporal_pyramid_levels = 3;
  int stereo_pyramid_levels = 2;
  int klt_iterations = 30;
  double klt_epsilon = 0.01;
  /// Epipolar check on the rectified pair: the right match must lie within this many pixels of
  /// the left feature's row.
  double epipolar_tolerance = 1.0;
  /// Accepted disparity range, pixels (a point at infinity has disparity 0).
  double min_disparity = 0.25;
  double max_disparity = 300.0;
  /// Circular matching (left k -> left k+1 -> right k+1 -> right k): the loop must close within
  /// this many pixels of the right-image position of frame k. New features are checked left ->
  /// right -> left with the same tolerance.
  double circular_tolerance = 1.0;
  /// RANSAC on temporal matches (fundamental matrix on left k -> left k+1): inlier threshold
  /// (pixels) and confidence. Skipped when the median flow is under ransac_min_parallax pixels
  /// (the model is degenerate without translation); the visual odometry's RANSAC then still
  /// rejects wrong temporal matches.
  double ransac_threshold = 1.0;
  double ransac_confidence = 0.999;
  double ransac_min_parallax = 2.0;
  /// Anchored tracking (0 = off): each track's frame-to-frame KLT position is refined by
  /// aligning the track's patch as it was in the frame the track was anchored at (its first, at
  /// first) under an affine warp, so that the track's error neither adds up from frame to frame
  /// nor follows the patch's change of scale and shear as the robot moves. A track keeps its
  /// anchor for anchor_frames frames; then, or when the alignment fails, it is anchored afresh
  /// where it is and goes on under a new id (to the estimator a new track).
  int anchor_frames = 12;
  /// The stereo match (left k -> right k) refined by aligning the left patch into the right image
  /// under the rectified pair's warp (rows stay rows; a slanted surface's patch is scaled and
  /// sheared along them), for new and continued tracks.
  bool stereo_affine = true;
  /// The patch of both alignments (pixels, odd), and how far (pixels) an alignment may move a
  /// position from KLT's before it is refused.
  int affine_window = 15;
  double affine_tolerance = 1.0;

  /// Every problem with the values, each naming the field and the bad value; empty when valid.
  [[nodiscard]] std::vector<std::string> validate() const;
};

/// Stereo visual odometry (StereoVisualOdometry).
struct OdometryOptions {
  /// Standard deviation of a tracked feature coordinate, pixels: weights the refinement and sets
  /// the scale of the reported covariance.
  double pixel_sigma = 0.5;
  /// PnP RANSAC (points triangulated at frame k-1, left positions at frame k): inlier
  /// reprojection threshold (pixels), iterations and confidence.
  double ransac_threshold = 2.0;
  int ransac_iterations = 200;
  double ransac_confidence = 0.999;
  /// Fewest RANSAC inliers for a motion estimate.
  int min_inliers = 12;
  /// Points of frame k-1 with a smaller disparity (pixels) are not triangulated.
  double min_disparity = 1.0;
  /// Gauss-Newton iterations of the refinement, and its inlier gate: a point whose weighted
  /// stereo reprojection error (chi-square, 3 degrees of freedom) exceeds this is left out.
  int refine_iterations = 10;
  double refine_chi2_gate = 11.34;  // 99 % of chi-square with 3 degrees of freedom
  /// When the motion cannot be estimated (too few inliers), the previous motion is repeated with
  /// these standard deviations per axis (metres, radians) as its covariance.
  double failure_translation_sigma = 0.5;
  double failure_rotation_sigma = 0.2;

  [[nodiscard]] std::vector<std::string> validate() const;
};

/// Object detections to stereo observations (ObjectObserver).
struct ObjectOptions {
  /// The disparity of a detection is measured on this central fraction of its box (each side),
  /// to stay on the object and off the background.
  double central_fraction = 0.5;
  /// Smallest measured region, pixels per side; smaller boxes are skipped.
  int min_region_size = 6;
  /// Smallest normalized cross-correlation of the region's match in the right image.
  double min_match_score = 0.7;
  /// Largest disparity searched, pixels.
  double max_disparity = 300.0;
  /// A match is ambiguous, and gives no observation, when another peak of the correlation along
  /// the row (more than half the region's width from the best) scores above this fraction of
  /// the best: a repeated texture or a weakly textured region, whose disparity may be another
  /// surface's. 1 refuses only exact ties.
  double ambiguity_ratio = 0.97;
  /// Left-right consistency: the matched right region, matched back along the left image's row,
  /// must land within this many pixels of the box's region; else the match is refused (an
  /// occluded or partly covered region whose right-image match is another surface's).
  double left_right_tolerance = 2.0;
  /// The disparity measures the object's visible surface; its centre lies deeper. The object is
  /// taken as a box whose depth is 2 * centre_depth_fraction times its width (0.5: about as deep
  /// as wide; 0: the surface itself), its near face at the measured depth, and the detection as
  /// that box's silhouette: off the optical axis the silhouette also shows the object's side,
  /// so the object is narrower than the detection's width at that depth (object_centre).
  double centre_depth_fraction = 0.5;
  /// Objects stand upright in the camera's rows (a level camera on a ground robot, objects on
  /// the floor): the detection's top or bottom edge is then the far edge of the top or bottom
  /// face the camera sees, and the centre's row is taken from that model instead of the box's
  /// middle row (object_centre). `concord frontend --up-axis` sets it when the up axis is the
  /// camera's vertical. Off: the box's middle row.
  bool upright = false;
  /// Boxes closer than this to the image border (pixels) are skipped (truncated boxes do not
  /// centre on the object).
  int border = 2;
  /// The detector's box-centre accuracy, pixels (one sigma): a property of the robot's detector,
  /// which the front-end cannot measure; it becomes object_noise (isotropic) in the suggested estimator
  /// config (estimator.yaml).
  double detection_sigma = 2.0;

  [[nodiscard]] std::vector<std::string> validate() const;
};

/// The whole front-end.
struct FrontendOptions {
  TrackerOptions tracker;
  OdometryOptions odometry;
  ObjectOptions objects;

  /// Problems of all parts, each prefixed with its part ("tracker.", "odometry.", "objects.").
  [[nodiscard]] std::vector<std::string> validate() const;
};

}  // namespace concord::frontend
