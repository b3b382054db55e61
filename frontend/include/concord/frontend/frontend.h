#pragma once
/// \file
/// The stereo front-end of one robot: a sequence's raw image pairs in, the estimator's FrameInput
/// out (odometry from the previous frame, object observations, point-feature tracks), frame by
/// frame. Per frame: load both images, undistort and rectify (StereoRectifier), track
/// (StereoTracker), estimate the motion (StereoVisualOdometry, or the robot's own odometry through
/// the same OdometrySource interface) and drop its outlier tracks, and turn the frame's
/// detections into stereo object observations (observe_object). Everything is in rectified pixels
/// of camera() (docs/frontend.md). OpenCV-free, so the daemon and the CLI include it freely.

#include <array>
#include <memory>
#include <vector>

#include "concord/estimator/types.h"
#include "concord/frontend/detections.h"
#include "concord/frontend/frontend_options.h"
#include "concord/frontend/sequence.h"
#include "concord/frontend/stereo_odometry.h"
#include "concord/frontend/tracking_counts.h"

namespace concord::frontend {

/// Wall time of one frame's stages, milliseconds.
struct FrameTimings {
  double load = 0.0;      ///< reading and decoding both images
  double rectify = 0.0;   ///< undistortion and rectification
  double track = 0.0;     ///< StereoTracker
  double odometry = 0.0;  ///< motion estimate
  double objects = 0.0;   ///< detections to observations
  double total = 0.0;
  /// CPU time of the processing thread over the whole frame, and without loading the images
  /// (what a robot whose camera driver delivers decoded images spends): independent of other load
  /// on the machine, the frame's work on one core when OpenCV runs single-threaded.
  double total_cpu = 0.0;
  double processing_cpu = 0.0;
};

/// Sets the number of threads OpenCV may use (1: everything on the calling thread). Process-wide.
void set_opencv_threads(int threads);

/// One processed frame.
struct FrontendFrame {
  /// What the estimator takes: frame number, T_body(k-1)_body(k) (absent at frame 0), object
  /// observations and point-feature tracks (rectified pixels).
  FrameInput input;
  /// Time stamp of the images, seconds.
  double timestamp = 0.0;
  /// The motion estimate behind input.T_previous_current (frames >= 1).
  MotionEstimate motion;
  TrackingCounts counts;
  /// Mean length (frames) of this frame's tracks.
  double mean_track_length = 0.0;
  /// The tracker's noise estimate from the stereo rows (TrackedFrame::row_noise_sigma).
  double row_noise_sigma = 0.0;
  /// The point features' alignment variances (TrackedFrame::alignment_variances), in the order
  /// of input.features.
  std::vector<std::array<float, 2>> alignment_variances;
  /// Detections of the frame, how many gave observations, and how many were refused for an
  /// ambiguous or left-right inconsistent stereo match (ObjectSkip).
  int detections = 0;
  int objects_observed = 0;
  /// The detector's class name of each object observation, parallel to input.objects.
  std::vector<std::string> object_class_names;
  int objects_ambiguous = 0;
  int objects_inconsistent = 0;
  FrameTimings timings;
};

class StereoFrontend {
 public:
  /// Sets up the front-end for `sequence`. `detections`: one list per frame (or empty: no
  /// objects), boxes in the input left image. `odometry`: the robot's own odometry, or null for
  /// stereo visual odometry. Throws FrontendError if the options or the calibration are unusable
  /// or the detections do not have one list per frame.
  StereoFrontend(StereoSequence sequence, const FrontendOptions& options,
                 std::vector<std::vector<Detection>> detections = {},
                 std::unique_ptr<OdometrySource> odometry = nullptr);
  ~StereoFrontend();
  StereoFrontend(const StereoFrontend&) = delete;
  StereoFrontend& operator=(const StereoFrontend&) = delete;

  /// The rectified camera every output is in.
  const StereoCamera& camera() const;
  const StereoSequence& sequence() const;
  int num_frames() const;
  /// Frames processed so far.
  int next_frame() const;
  bool done() const { return next_frame() >= num_frames(); }

  /// Processes the next frame. Throws FrontendError if an image cannot be read or decoded, and
  /// std::logic_error when done().
  [[nodiscard]] FrontendFrame process_next();

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace concord::frontend
