#pragma once
/// \file
/// Stereo feature tracking on rectified image pairs (the paper's §VI-A; anchors: OpenVINS
/// ov_core TrackKLT, Kimera-VIO's stereo front-end). Per frame:
///
///   1. Temporal KLT: every track's left position at k-1 is followed into the left image at k.
///   2. Stereo KLT: left k -> right k, starting from the track's previous disparity.
///   3. Circular matching: right k -> right k-1 must close the loop on the track's right position
///      at k-1 (left k-1 -> left k -> right k -> right k-1 -> left k-1).
///   4. Epipolar check: on rectified images the right match must be on the same row, at a
///      disparity in range.
///   5. RANSAC on temporal matches: a fundamental matrix fit on left k-1 -> left k.
///   6. Replenishment: FAST corners on a grid, away from the tracked ones, matched left -> right
///      and checked right -> left and on the row, get new track ids.
///
/// Names OpenCV types: for the front-end library and its tests.

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <opencv2/core.hpp>
#include <span>
#include <vector>

#include "concord/estimator/types.h"
#include "concord/frontend/frontend_options.h"
#include "concord/frontend/tracking_counts.h"

namespace concord::frontend {

class AffineTemplate;

/// The tracks of one frame.
struct TrackedFrame {
  /// Frame number (0 for the first frame tracked).
  int frame = 0;
  /// One stereo observation per live track: id and rectified (u_left, v_left, u_right, v_right).
  std::vector<StereoObservation> observations;
  /// Frames each track has been observed, including this one (same order as observations).
  std::vector<int> track_lengths;
  /// Each observation's Lucas-Kanade position variances, pixels^2 per axis (same order as
  /// observations): of the left image's match (the affine alignment of the track's anchor patch)
  /// and of the right image's against the left (the stereo alignment). NaN where no alignment
  /// measured it: a track's first frame in the left image (its anchor: the point it follows), a
  /// match the alignment did not refine.
  std::vector<std::array<float, 2>> alignment_variances;
  TrackingCounts counts;
  /// Median left-image flow of the continued tracks from k-1 to k, pixels.
  double median_flow = 0.0;
  /// Robust standard deviation (1.4826 median absolute deviation / sqrt 2) of the row difference
  /// v_left - v_right of this frame's stereo matches before the epipolar check: an estimate of
  /// the per-coordinate tracking noise from the rectified geometry alone (no ground truth). 0 when
  /// there are fewer than 10 matches.
  double row_noise_sigma = 0.0;
};

/// Where a test may alter matched positions (like a failpoint): after the temporal KLT
/// (positions in the left image at k), after the stereo KLT of continued tracks (right image at
/// k), after the stereo KLT of new features.
enum class MatchStage { kTemporal, kStereo, kNewStereo };

class StereoTracker {
 public:
  /// Called with a stage and the matched positions of that stage, which it may change. For tests.
  using MatchHook = std::function<void(MatchStage stage, std::vector<cv::Point2f>& points)>;

  /// Throws FrontendError if the options are invalid.
  explicit StereoTracker(const TrackerOptions& options);

  /// Tracks a rectified 8-bit grey pair (both of one size) as the next frame.
  [[nodiscard]] TrackedFrame track(const cv::Mat& left, const cv::Mat& right);

  /// Ends the given tracks (e.g. the visual odometry's outliers) so they do not continue.
  void drop_tracks(std::span<const LandmarkId> ids);

  /// Installs a hook (tests only).
  void set_match_hook(MatchHook hook) { hook_ = std::move(hook); }

  const TrackerOptions& options() const { return options_; }

 private:
  /// The state of one live track: id, rectified positions at the last frame, length.
  struct Tracks {
    std::vector<LandmarkId> ids;
    std::vector<cv::Point2f> left;
    std::vector<cv::Point2f> right;
    std::vector<int> lengths;
    /// Anchored tracking: the frame each track was anchored at, its patch there (prepared for
    /// alignment; null when anchoring is off or the patch has too little texture), and the affine
    /// part of the patch's warp from there to now; the affine part of its patch's warp from the
    /// left to the right image.
    std::vector<int> anchor_frames;
    std::vector<std::shared_ptr<const AffineTemplate>> anchors;
    std::vector<cv::Matx22f> temporal_warps;
    std::vector<cv::Matx22f> stereo_warps;
    /// This frame's alignment variances (TrackedFrame::alignment_variances).
    std::vector<std::array<float, 2>> variances;
    std::size_t size() const { return ids.size(); }
    void keep(const std::vector<unsigned char>& keep_mask);
    void sort_by_id();
  };

  void continue_tracks(const std::vector<cv::Mat>& left_pyramid,
                       const std::vector<cv::Mat>& right_pyramid, const cv::Size& size,
                       TrackedFrame& out);
  void add_features(const cv::Mat& left, const std::vector<cv::Mat>& left_pyramid,
                    const std::vector<cv::Mat>& right_pyramid, TrackedFrame& out);
  /// The patch of `image` at `point` prepared as a track's anchor (null when anchoring is off or
  /// the patch has too little texture: the track is then anchored afresh at the next frame).
  std::shared_ptr<const AffineTemplate> make_anchor(const cv::Mat& image,
                                                    const cv::Point2f& point) const;
  /// Aligns `patch` into `image`, starting at `point` with the affine part `warp`; on success
  /// updates both (and `variance`, the fit's position variance) and returns true. Fails when the
  /// alignment fails or lands more than affine_tolerance away.
  bool refine_affine(const AffineTemplate& patch, const cv::Mat& image, cv::Point2f& point,
                     cv::Matx22f& warp, float& variance) const;
  bool inside(const cv::Point2f& point, const cv::Size& size) const;
  /// The epipolar check of a rectified match: on the same row (within the tolerance), its
  /// disparity in [min_disparity, max_disparity].
  bool on_row_in_range(const cv::Point2f& left, const cv::Point2f& right) const;

  TrackerOptions options_;
  MatchHook hook_;
  Tracks tracks_;
  std::vector<cv::Mat> previous_left_pyramid_;
  std::vector<cv::Mat> previous_right_pyramid_;
  std::vector<cv::Mat> spare_left_pyramid_;
  std::vector<cv::Mat> spare_right_pyramid_;
  cv::Mat free_mask_;
  LandmarkId next_id_ = 0;
  int frame_ = 0;
  /// The median flow of the last frame's tracks (left image, pixels): where the next frame's
  /// temporal tracking starts from.
  cv::Point2f predicted_flow_{0.0f, 0.0f};
};

}  // namespace concord::frontend
