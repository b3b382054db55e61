// Stereo visual odometry as math: exact motion from exact tracks, RANSAC against gross outliers,
// and a covariance that matches the spread of the estimates (Monte Carlo).
#include <gtest/gtest.h>

#include <random>

#include "concord/estimator/lie.h"
#include "concord/frontend/sequence.h"
#include "concord/frontend/stereo_odometry.h"

namespace concord::frontend {
namespace {

/// A rectified 640 x 480 rig, body = camera.
StereoCamera rig() {
  StereoCamera camera;
  camera.K << 450.0, 0.0, 320.0, 0.0, 450.0, 240.0, 0.0, 0.0, 1.0;
  camera.T_cam0_cam1.translation() = Eigen::Vector3d(0.3, 0.0, 0.0);
  return camera;
}

Eigen::Vector4d observe(const StereoCamera& camera, const Eigen::Vector3d& p) {
  const double fx = camera.K(0, 0), cx = camera.K(0, 2), cy = camera.K(1, 2);
  return Eigen::Vector4d(fx * p.x() / p.z() + cx, fx * p.y() / p.z() + cy,
                         fx * (p.x() - camera.baseline()) / p.z() + cx, fx * p.y() / p.z() + cy);
}

/// Tracks of `count` points seen from two poses related by T_previous_current, with pixel noise.
struct TwoFrames {
  std::vector<StereoObservation> previous, current;
};

TwoFrames make_frames(const StereoCamera& camera, const Eigen::Isometry3d& T_previous_current,
                      int count, double noise, std::mt19937& random) {
  std::uniform_real_distribution<double> lateral(-4.0, 4.0), depth(2.0, 20.0);
  std::normal_distribution<double> pixel(0.0, noise);
  TwoFrames frames;
  for (int id = 0; static_cast<int>(frames.previous.size()) < count; ++id) {
    const double z = depth(random);
    const Eigen::Vector3d p(lateral(random) * z / 8.0, 0.6 * lateral(random) * z / 8.0, z);
    const Eigen::Vector3d q = T_previous_current.inverse() * p;
    if (q.z() < 1.0) continue;
    StereoObservation before{id, observe(camera, p)}, after{id, observe(camera, q)};
    for (int c = 0; c < 4; ++c) {
      before.uv(c) += pixel(random);
      after.uv(c) += pixel(random);
    }
    frames.previous.push_back(before);
    frames.current.push_back(after);
  }
  return frames;
}

Eigen::Isometry3d motion() {
  lie::Vector6d xi;
  xi << 0.05, -0.02, 0.3, 0.01, -0.03, 0.02;
  return lie::se3_exp(xi);
}

TEST(FrontendOdometry, ExactTracksGiveTheExactMotion) {
  std::mt19937 random(1);
  const StereoCamera camera = rig();
  const TwoFrames frames = make_frames(camera, motion(), 80, 0.0, random);
  StereoVisualOdometry odometry(camera, {});
  const MotionEstimate estimate = odometry.estimate(1, frames.previous, frames.current);
  ASSERT_TRUE(estimate.valid);
  EXPECT_EQ(estimate.inliers, 80);
  EXPECT_TRUE(estimate.outliers.empty());
  EXPECT_LT(lie::se3_log(motion().inverse() * estimate.T_previous_current).norm(), 1e-8);
}

TEST(FrontendOdometry, RansacFindsTheMotionAmongGrossOutliersAndNamesThem) {
  std::mt19937 random(2);
  const StereoCamera camera = rig();
  TwoFrames frames = make_frames(camera, motion(), 100, 0.3, random);
  std::uniform_real_distribution<double> jump(-40.0, 40.0);
  for (std::size_t index = 0; index < frames.current.size(); index += 4) {  // 25 % wrong matches
    frames.current[index].uv(0) += 15.0 + std::abs(jump(random));
    frames.current[index].uv(2) += 15.0 + std::abs(jump(random));
  }
  StereoVisualOdometry odometry(camera, {});
  const MotionEstimate estimate = odometry.estimate(1, frames.previous, frames.current);
  ASSERT_TRUE(estimate.valid);
  EXPECT_EQ(estimate.outliers.size(), 25u);
  for (const LandmarkId id : estimate.outliers) EXPECT_EQ(id % 4, 0);
  const lie::Vector6d error = lie::se3_log(motion().inverse() * estimate.T_previous_current);
  EXPECT_LT(error.head<3>().norm(), 0.01);
  EXPECT_LT(error.tail<3>().norm(), 0.002);
}

TEST(FrontendOdometry, CovarianceMatchesTheSpreadOfTheEstimates) {
  // With the pixel noise the odometry assumes, xi^T Sigma^-1 xi averages 6 (six degrees of
  // freedom) over many draws.
  std::mt19937 random(3);
  const StereoCamera camera = rig();
  OdometryOptions options;
  options.pixel_sigma = 0.5;
  StereoVisualOdometry odometry(camera, options);
  double nees = 0.0;
  const int trials = 300;
  for (int trial = 0; trial < trials; ++trial) {
    const TwoFrames frames = make_frames(camera, motion(), 60, options.pixel_sigma, random);
    const MotionEstimate estimate = odometry.estimate(1, frames.previous, frames.current);
    ASSERT_TRUE(estimate.valid);
    const lie::Vector6d error = lie::se3_log(motion().inverse() * estimate.T_previous_current);
    nees += error.dot(estimate.covariance.ldlt().solve(error));
  }
  nees /= trials;
  EXPECT_GT(nees, 4.8);
  EXPECT_LT(nees, 7.0);
}

TEST(FrontendOdometry, CovarianceIsCarriedIntoTheBodyFrame) {
  std::mt19937 random(4);
  StereoCamera camera = rig();
  Eigen::Matrix3d R_cam_body;
  R_cam_body << 0, -1, 0, 0, 0, -1, 1, 0, 0;  // body x forward, y left, z up
  camera.T_cam0_body.linear() = R_cam_body;
  camera.T_cam0_body.translation() = Eigen::Vector3d(0.1, -0.2, 0.05);
  const Eigen::Isometry3d T_body_motion = motion();
  const Eigen::Isometry3d T_camera_motion =
      camera.T_cam0_body * T_body_motion * camera.T_cam0_body.inverse();
  const TwoFrames frames = make_frames(camera, T_camera_motion, 60, 0.0, random);
  StereoVisualOdometry odometry(camera, {});
  const MotionEstimate estimate = odometry.estimate(1, frames.previous, frames.current);
  ASSERT_TRUE(estimate.valid);
  EXPECT_LT(lie::se3_log(T_body_motion.inverse() * estimate.T_previous_current).norm(), 1e-8);
  // Forward (body x, camera z) is the worst-known translation of a forward-looking stereo rig.
  EXPECT_GT(estimate.covariance(0, 0), estimate.covariance(1, 1));
  EXPECT_GT(estimate.covariance(0, 0), estimate.covariance(2, 2));
}

TEST(FrontendOdometry, TooFewTracksRepeatTheLastMotionWithTheFailureCovariance) {
  std::mt19937 random(5);
  const StereoCamera camera = rig();
  StereoVisualOdometry odometry(camera, {});
  const TwoFrames frames = make_frames(camera, motion(), 60, 0.0, random);
  ASSERT_TRUE(odometry.estimate(1, frames.previous, frames.current).valid);
  const std::vector<StereoObservation> few(frames.current.begin(), frames.current.begin() + 5);
  const MotionEstimate failed = odometry.estimate(2, frames.current, few);
  EXPECT_FALSE(failed.valid);
  EXPECT_LT(lie::se3_log(motion().inverse() * failed.T_previous_current).norm(), 1e-8);
  EXPECT_DOUBLE_EQ(failed.covariance(0, 0), 0.25);
  EXPECT_DOUBLE_EQ(failed.covariance(5, 5), 0.04);
}

TEST(FrontendOdometry, InvalidOptionsAreNamed) {
  OdometryOptions options;
  options.min_inliers = 2;
  options.pixel_sigma = 0.0;
  try {
    StereoVisualOdometry odometry(rig(), options);
    FAIL() << "expected FrontendError";
  } catch (const FrontendError& error) {
    EXPECT_NE(std::string(error.what()).find("odometry.min_inliers = 2"), std::string::npos);
    EXPECT_NE(std::string(error.what()).find("odometry.pixel_sigma"), std::string::npos);
  }
}

}  // namespace
}  // namespace concord::frontend
