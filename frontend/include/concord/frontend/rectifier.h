#pragma once
/// \file
/// Undistortion and stereo rectification of raw image pairs (OpenCV calib3d: stereoRectify,
/// initUndistortRectifyMap, remap). After rectification both images share one pinhole K, the
/// right camera sits at +baseline along the left camera's x axis, and a point has the same row
/// in both images: the front-end's epipolar check is a row check. Input that is already rectified
/// (StereoRig::rectified, KITTI) passes through unchanged.
///
/// Names OpenCV types: for the front-end library and its tests.

#include <opencv2/core.hpp>

#include "concord/estimator/types.h"
#include "concord/frontend/sequence.h"

namespace concord::frontend {

class StereoRectifier {
 public:
  /// Builds the rectification of `rig`. Throws FrontendError if the rig is unusable or the
  /// rectification degenerate (e.g. the "right" camera is on the left).
  explicit StereoRectifier(const StereoRig& rig);

  /// The rectified stereo camera: K (pixels), T_cam0_body (body into the rectified left optical
  /// frame) and T_cam0_cam1 = translation (baseline, 0, 0).
  const StereoCamera& camera() const { return camera_; }
  cv::Size image_size() const { return size_; }

  /// Rectified 8-bit grey images of a raw pair (converted to grey if in colour). Throws
  /// FrontendError if an image is empty or not of the calibrated size.
  void rectify(const cv::Mat& left_raw, const cv::Mat& right_raw, cv::Mat& left,
               cv::Mat& right) const;

  /// The rectified left-image position of a raw left-image position.
  cv::Point2d rectify_left_point(const cv::Point2d& raw) const;

 private:
  bool pass_through_ = false;
  cv::Size size_;
  StereoCamera camera_;
  cv::Mat left_K_, left_distortion_, left_rotation_, left_projection_;
  cv::Mat left_map_1_, left_map_2_, right_map_1_, right_map_2_;
};

/// Converts an image to 8-bit grey (from 8-bit colour or grey; 16-bit is scaled down).
cv::Mat to_grey(const cv::Mat& image);

}  // namespace concord::frontend
