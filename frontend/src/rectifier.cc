#include "concord/frontend/rectifier.h"

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

namespace concord::frontend {

namespace {

cv::Mat to_cv(const Eigen::MatrixXd& matrix) {
  cv::Mat out(static_cast<int>(matrix.rows()), static_cast<int>(matrix.cols()), CV_64F);
  for (int row = 0; row < out.rows; ++row) {
    for (int column = 0; column < out.cols; ++column)
      out.at<double>(row, column) = matrix(row, column);
  }
  return out;
}

cv::Mat distortion_of(const CameraIntrinsics& camera) {
  return to_cv(Eigen::VectorXd(camera.distortion).transpose());
}

void check_image(const cv::Mat& image, const cv::Size& size, const char* which) {
  if (image.empty()) throw FrontendError(std::string(which) + " image is empty");
  if (image.size() != size) {
    throw FrontendError(std::string(which) + " image is " + std::to_string(image.cols) + "x" +
                        std::to_string(image.rows) + ", the calibration's " +
                        std::to_string(size.width) + "x" + std::to_string(size.height));
  }
}

}  // namespace

cv::Mat to_grey(const cv::Mat& image) {
  cv::Mat grey = image;
  if (grey.depth() == CV_16U) grey.convertTo(grey, CV_8U, 1.0 / 256.0);
  if (grey.channels() == 3) {
    cv::cvtColor(grey, grey, cv::COLOR_BGR2GRAY);
  } else if (grey.channels() == 4) {
    cv::cvtColor(grey, grey, cv::COLOR_BGRA2GRAY);
  }
  return grey;
}

StereoRectifier::StereoRectifier(const StereoRig& rig) {
  const std::vector<std::string> problems = rig.problems();
  if (!problems.empty()) {
    std::string message = "unusable stereo calibration:";
    for (const std::string& problem : problems) message += " " + problem;
    throw FrontendError(message);
  }
  size_ = cv::Size(rig.left.width, rig.left.height);
  if (rig.rectified) {
    pass_through_ = true;
    camera_.K = rig.left.K();
    camera_.T_cam0_body = rig.T_cam0_body;
    camera_.T_cam0_cam1 = Eigen::Isometry3d::Identity();
    camera_.T_cam0_cam1.translation() = Eigen::Vector3d(rig.T_cam0_cam1.translation().norm(), 0, 0);
    return;
  }
  // stereoRectify wants the motion from the left to the right camera frame: p_cam1 = R p_cam0 + T.
  const Eigen::Isometry3d T_cam1_cam0 = rig.T_cam0_cam1.inverse();
  left_K_ = to_cv(rig.left.K());
  left_distortion_ = distortion_of(rig.left);
  const cv::Mat right_K = to_cv(rig.right.K());
  const cv::Mat right_distortion = distortion_of(rig.right);
  cv::Mat right_rotation, right_projection, disparity_to_depth;
  // alpha = 0: the rectified images show only valid pixels (no black borders to track).
  cv::stereoRectify(left_K_, left_distortion_, right_K, right_distortion, size_,
                    to_cv(T_cam1_cam0.rotation()), to_cv(T_cam1_cam0.translation()), left_rotation_,
                    right_rotation, left_projection_, right_projection, disparity_to_depth,
                    cv::CALIB_ZERO_DISPARITY, 0.0, size_);
  const double fx = left_projection_.at<double>(0, 0);
  const double baseline = -right_projection.at<double>(0, 3) / right_projection.at<double>(0, 0);
  if (!(fx > 0.0 && std::isfinite(baseline) && baseline > 1e-3)) {
    throw FrontendError("stereo rectification failed (rectified focal length " +
                        std::to_string(fx) + ", baseline " + std::to_string(baseline) +
                        " m): is the right camera really on the right of the left one?");
  }
  cv::initUndistortRectifyMap(left_K_, left_distortion_, left_rotation_, left_projection_, size_,
                              CV_16SC2, left_map_1_, left_map_2_);
  cv::initUndistortRectifyMap(right_K, right_distortion, right_rotation, right_projection, size_,
                              CV_16SC2, right_map_1_, right_map_2_);

  camera_.K << fx, 0.0, left_projection_.at<double>(0, 2), 0.0, left_projection_.at<double>(1, 1),
      left_projection_.at<double>(1, 2), 0.0, 0.0, 1.0;
  Eigen::Matrix3d R_rectified_cam0;
  for (int row = 0; row < 3; ++row) {
    for (int column = 0; column < 3; ++column) {
      R_rectified_cam0(row, column) = left_rotation_.at<double>(row, column);
    }
  }
  Eigen::Isometry3d T_rectified_cam0 = Eigen::Isometry3d::Identity();
  T_rectified_cam0.linear() = R_rectified_cam0;
  camera_.T_cam0_body = T_rectified_cam0 * rig.T_cam0_body;
  camera_.T_cam0_cam1 = Eigen::Isometry3d::Identity();
  camera_.T_cam0_cam1.translation() = Eigen::Vector3d(baseline, 0.0, 0.0);
}

void StereoRectifier::rectify(const cv::Mat& left_raw, const cv::Mat& right_raw, cv::Mat& left,
                              cv::Mat& right) const {
  check_image(left_raw, size_, "left");
  check_image(right_raw, size_, "right");
  const cv::Mat left_grey = to_grey(left_raw);
  const cv::Mat right_grey = to_grey(right_raw);
  if (pass_through_) {
    left = left_grey;
    right = right_grey;
    return;
  }
  cv::remap(left_grey, left, left_map_1_, left_map_2_, cv::INTER_LINEAR);
  cv::remap(right_grey, right, right_map_1_, right_map_2_, cv::INTER_LINEAR);
}

cv::Point2d StereoRectifier::rectify_left_point(const cv::Point2d& raw) const {
  if (pass_through_) return raw;
  std::vector<cv::Point2d> in{raw}, out;
  cv::undistortPoints(in, out, left_K_, left_distortion_, left_rotation_, left_projection_);
  return out.front();
}

}  // namespace concord::frontend
