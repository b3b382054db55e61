// The front-end on real images: the repository's four EuRoC V1_01 stereo pairs (raw, with
// radial-tangential distortion; the vehicle stands still). Stereo matches are found and agree
// with the calibration; the visual odometry reports no motion.
#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>

#include "concord/estimator/lie.h"
#include "concord/frontend/frontend.h"
#include "concord/frontend/rectifier.h"
#include "concord/frontend/stereo_tracker.h"
#include "frontend_test_support.h"

namespace concord::frontend {
namespace {

TEST(FrontendEuroc, StereoMatchesAgreeWithTheRawCalibration) {
  const StereoSequence sequence = read_stereo_sequence(testing::euroc_frames());
  const StereoRectifier rectifier(sequence.rig);
  cv::Mat left, right;
  rectifier.rectify(cv::imread(sequence.left_images[0].string(), cv::IMREAD_UNCHANGED),
                    cv::imread(sequence.right_images[0].string(), cv::IMREAD_UNCHANGED), left,
                    right);
  StereoTracker tracker(TrackerOptions{});
  const TrackedFrame frame = tracker.track(left, right);
  EXPECT_GE(frame.observations.size(), 100u);

  // Back to the raw cameras: a rectified ray K^-1 (u, v, 1) is R_rect_raw0 times the raw left
  // ray, and the right camera is rectified by the same turn after the raw relative rotation.
  // Every match must satisfy the raw epipolar constraint x1^T [t]x R x0 = 0 of sensor.yaml.
  const StereoCamera& camera = rectifier.camera();
  const Eigen::Matrix3d R_rect_raw0 =
      camera.T_cam0_body.linear() * sequence.rig.T_cam0_body.linear().transpose();
  const Eigen::Isometry3d T_raw1_raw0 = sequence.rig.T_cam0_cam1.inverse();
  const Eigen::Matrix3d R_rect_raw1 = R_rect_raw0 * sequence.rig.T_cam0_cam1.linear();
  const Eigen::Matrix3d essential = lie::skew(T_raw1_raw0.translation()) * T_raw1_raw0.linear();
  const Eigen::Matrix3d K_inverse = camera.K.inverse();
  std::vector<double> residuals;
  for (const StereoObservation& match : frame.observations) {
    const Eigen::Vector3d x0 =
        R_rect_raw0.transpose() * K_inverse * Eigen::Vector3d(match.uv(0), match.uv(1), 1.0);
    const Eigen::Vector3d x1 =
        R_rect_raw1.transpose() * K_inverse * Eigen::Vector3d(match.uv(2), match.uv(3), 1.0);
    // Distance of x1 from the epipolar line E x0, in pixels of the raw right camera.
    const Eigen::Vector3d line = essential * (x0 / x0.z());
    const double distance = std::abs((x1 / x1.z()).dot(line)) / line.head<2>().norm();
    residuals.push_back(distance * sequence.rig.right.fx);
    // In front of the rig at a plausible indoor depth.
    const double depth = camera.K(0, 0) * camera.baseline() / (match.uv(0) - match.uv(2));
    EXPECT_GT(depth, 0.3);
    EXPECT_LT(depth, 30.0);
  }
  std::sort(residuals.begin(), residuals.end());
  EXPECT_LT(residuals[residuals.size() / 2], 0.5);
  EXPECT_LT(residuals[residuals.size() * 95 / 100], 1.5);
}

TEST(FrontendEuroc, VisualOdometryReportsNoMotion) {
  // Frames 0.65 s apart; the vehicle moves less than 2 mm over the whole set.
  StereoFrontend frontend(read_stereo_sequence(testing::euroc_frames()), FrontendOptions{});
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  const FrontendFrame first = frontend.process_next();
  EXPECT_GE(first.input.features.size(), 100u);
  while (!frontend.done()) {
    const FrontendFrame frame = frontend.process_next();
    ASSERT_TRUE(frame.motion.valid);
    EXPECT_GE(frame.motion.inliers, 80);
    const lie::Vector6d step = lie::se3_log(*frame.input.T_previous_current);
    EXPECT_LT(step.head<3>().norm(), 0.002) << "frame " << frame.input.frame;
    EXPECT_LT(step.tail<3>().norm(), 0.002) << "frame " << frame.input.frame;
    // The reported uncertainty is millimetres, not metres.
    EXPECT_LT(std::sqrt(frame.motion.covariance.diagonal().head<3>().maxCoeff()), 0.005);
    pose = pose * *frame.input.T_previous_current;
  }
  EXPECT_LT(pose.translation().norm(), 0.005);
}

}  // namespace
}  // namespace concord::frontend
