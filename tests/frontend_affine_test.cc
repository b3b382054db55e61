// The affine patch alignment behind anchored tracking and the stereo refinement
// (frontend/src/affine_patch.h), on images warped by a known affine map: the warp and the
// position recovered, brightness changes ignored, a translation-only KLT biased where the
// alignment is not, the rectified pair's model keeping rows at their height, and the failures.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "affine_patch.h"
#include "frontend_test_support.h"

namespace concord::frontend {
namespace {

/// The tests' smooth random texture, its contrast stretched over most of the grey range.
cv::Mat texture(int rows, int columns, int seed) {
  cv::Mat image = testing::random_texture(cv::Size(columns, rows), seed);
  cv::normalize(image, image, 20.0, 235.0, cv::NORM_MINMAX);
  return image;
}

/// `source` seen through x_target = A (x_source - centre) + target_centre, times `gain` plus
/// `offset` in brightness.
cv::Mat warped(const cv::Mat& source, const cv::Matx22f& A, const cv::Point2f& centre,
               const cv::Point2f& target_centre, double gain = 1.0, double offset = 0.0) {
  const cv::Vec2f shift = cv::Vec2f(target_centre.x, target_centre.y) - A * cv::Vec2f(centre.x, centre.y);
  const cv::Matx23f forward(A(0, 0), A(0, 1), shift[0], A(1, 0), A(1, 1), shift[1]);
  cv::Mat target;
  cv::warpAffine(source, target, cv::Mat(forward), source.size(), cv::INTER_CUBIC,
                 cv::BORDER_REFLECT_101);
  target.convertTo(target, CV_8U, gain, offset);
  return target;
}

double distance(const cv::Point2f& a, const cv::Point2f& b) {
  return std::hypot(static_cast<double>(a.x - b.x), static_cast<double>(a.y - b.y));
}

TEST(AffineAlignment, RecoversAKnownWarpAndPositionDespiteABrightnessChange) {
  const cv::Mat image = texture(160, 160, 7);
  const cv::Point2f centre(80.3f, 79.6f), truth(83.7f, 77.2f);
  // A patch seen 12 % larger, turned by 4 degrees and sheared, 30 % brighter and offset.
  const float c = std::cos(0.07f), s = std::sin(0.07f);
  const cv::Matx22f A = cv::Matx22f(1.12f, 0.0f, 0.0f, 1.12f) * cv::Matx22f(c, -s, s, c) *
                        cv::Matx22f(1.0f, 0.05f, 0.0f, 1.0f);
  const cv::Mat target = warped(image, A, centre, truth, 1.3, -15.0);

  AffineWarp warp;
  warp.t = truth + cv::Point2f(0.6f, -0.5f);  // where a KLT might have put it
  AffineAlignmentOptions options;
  ASSERT_TRUE(align_affine(image, centre, target, warp, options));
  EXPECT_LT(distance(warp.t, truth), 0.03);
  for (int row = 0; row < 2; ++row) {
    for (int column = 0; column < 2; ++column) EXPECT_NEAR(warp.A(row, column), A(row, column), 0.01);
  }
}

TEST(AffineAlignment, FollowsAGrowingPatchThatTranslationOnlyKltMisplaces) {
  // A patch whose texture fades out to its left (as around most corners, the texture lies on one
  // side). Seen 15 % larger, translation-only KLT is pulled towards the texture.
  const cv::Mat textured = texture(160, 160, 11);
  cv::Mat contrast(160, 160, CV_32F);
  for (int row = 0; row < 160; ++row) {
    for (int column = 0; column < 160; ++column) {
      contrast.at<float>(row, column) = std::clamp((column - 72) / 16.0f, 0.1f, 1.0f);
    }
  }
  cv::Mat faded;
  textured.convertTo(faded, CV_32F);
  faded = (faded - 128.0f).mul(contrast) + 128.0f;
  cv::Mat image;
  faded.convertTo(image, CV_8U);
  const cv::Point2f corner(80.0f, 80.0f), truth(81.4f, 78.9f);
  const cv::Matx22f A(1.15f, 0.0f, 0.0f, 1.15f);
  const cv::Mat target = warped(image, A, corner, truth);

  AffineWarp warp;
  warp.t = truth;
  AffineAlignmentOptions options;
  ASSERT_TRUE(align_affine(image, corner, target, warp, options));
  const double affine_error = distance(warp.t, truth);

  std::vector<cv::Point2f> from{corner}, to{truth};
  std::vector<unsigned char> status;
  std::vector<float> errors;
  cv::calcOpticalFlowPyrLK(image, target, from, to, status, errors,
                           cv::Size(options.side, options.side), 0,
                           cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 30, 0.01),
                           cv::OPTFLOW_USE_INITIAL_FLOW);
  ASSERT_TRUE(status[0]);
  const double klt_error = distance(to[0], truth);
  EXPECT_LT(affine_error, 0.06);
  EXPECT_GT(klt_error, 4.0 * affine_error);
  EXPECT_GT(klt_error, 0.25);
}

TEST(AffineAlignment, TheRectifiedPairsWarpKeepsRowsAtTheirHeight) {
  const cv::Mat left = texture(160, 200, 3);
  const cv::Point2f centre(120.2f, 80.5f), truth(88.9f, 80.7f);
  // A slanted surface: the right view is compressed and sheared along the rows.
  const cv::Matx22f A(0.93f, 0.06f, 0.0f, 1.0f);
  const cv::Mat right = warped(left, A, centre, truth);
  AffineWarp warp;
  warp.t = truth + cv::Point2f(-0.5f, 0.2f);
  AffineAlignmentOptions options;
  options.model = WarpModel::kRectifiedStereo;
  ASSERT_TRUE(align_affine(left, centre, right, warp, options));
  EXPECT_LT(distance(warp.t, truth), 0.03);
  EXPECT_NEAR(warp.A(0, 0), A(0, 0), 0.01);
  EXPECT_NEAR(warp.A(0, 1), A(0, 1), 0.01);
  // The second row of the warp is not fitted: it stays the identity's.
  EXPECT_NEAR(warp.A(1, 0), 0.0f, 1e-6);
  EXPECT_NEAR(warp.A(1, 1), 1.0f, 1e-6);
}

TEST(AffineAlignment, FailsOnAFlatPatchAnEdgeAndAtTheBorder) {
  const cv::Mat flat(100, 100, CV_8U, cv::Scalar(90));
  AffineWarp warp;
  warp.t = cv::Point2f(50.0f, 50.0f);
  EXPECT_FALSE(align_affine(flat, cv::Point2f(50.0f, 50.0f), flat, warp, {}));

  // A vertical edge pins x, not y.
  cv::Mat edge(100, 100, CV_8U, cv::Scalar(40));
  edge(cv::Rect(50, 0, 50, 100)).setTo(cv::Scalar(200));
  cv::GaussianBlur(edge, edge, cv::Size(0, 0), 1.0);
  warp = AffineWarp{};
  warp.t = cv::Point2f(50.3f, 50.0f);
  EXPECT_FALSE(align_affine(edge, cv::Point2f(50.0f, 50.0f), edge, warp, {}));

  const cv::Mat image = texture(100, 100, 5);
  warp = AffineWarp{};
  warp.t = cv::Point2f(3.0f, 50.0f);  // the patch would reach past the left border
  EXPECT_FALSE(align_affine(image, cv::Point2f(50.0f, 50.0f), image, warp, {}));
}

TEST(AffineAlignment, APreparedTemplateFollowsItsPatchThroughASequenceOfWarps) {
  // An anchored track: one template, prepared once, aligned frame after frame into images in
  // which its patch grows and turns, each fit starting from the last; a template prepared afresh
  // from the same patch at every frame gives the same warps.
  const cv::Mat image = texture(200, 200, 11);
  const cv::Point2f centre(100.4f, 99.7f);
  AffineTemplate anchor;
  ASSERT_TRUE(anchor.prepare(image, centre, WarpModel::kAffine, 15));
  ASSERT_TRUE(anchor.valid());
  EXPECT_GE(anchor.bytes(), 15u * 15u * 7u * sizeof(float));
  AffineWarp kept, fresh;
  kept.t = fresh.t = centre;
  for (int frame = 1; frame <= 8; ++frame) {
    const float scale = 1.0f + 0.03f * static_cast<float>(frame);
    const float angle = 0.01f * static_cast<float>(frame);
    const cv::Matx22f A = cv::Matx22f(scale, 0.0f, 0.0f, scale) *
                          cv::Matx22f(std::cos(angle), -std::sin(angle), std::sin(angle),
                                      std::cos(angle));
    const cv::Point2f truth = centre + cv::Point2f(1.3f * static_cast<float>(frame),
                                                   -0.7f * static_cast<float>(frame));
    const cv::Mat target = warped(image, A, centre, truth);
    ASSERT_TRUE(anchor.align(target, kept, 15, 0.02)) << "frame " << frame;
    ASSERT_TRUE(align_affine(image, centre, target, fresh, {})) << "frame " << frame;
    EXPECT_LT(distance(kept.t, truth), 0.05) << "frame " << frame;
    EXPECT_LT(distance(kept.t, fresh.t), 1e-3) << "frame " << frame;
    for (int row = 0; row < 2; ++row) {
      for (int column = 0; column < 2; ++column) {
        EXPECT_NEAR(kept.A(row, column), A(row, column), 0.01) << "frame " << frame;
      }
    }
  }

  // Prepared again on a flat patch, the same object is no longer valid and aligns nothing.
  const cv::Mat flat(100, 100, CV_8U, cv::Scalar(90));
  EXPECT_FALSE(anchor.prepare(flat, cv::Point2f(50.0f, 50.0f), WarpModel::kAffine, 15));
  EXPECT_FALSE(anchor.valid());
  AffineWarp warp;
  warp.t = cv::Point2f(100.0f, 100.0f);
  EXPECT_FALSE(anchor.align(image, warp, 15, 0.02));
}

TEST(AffineAlignment, ItsPositionVarianceFollowsTheImageNoiseAndTheErrorsUpToAScale) {
  // The same patch aligned into copies of its image with Gaussian noise added: the variance the
  // alignment reports grows with the noise's variance, as the spread of its errors does.
  const cv::Mat image = texture(160, 160, 21);
  const cv::Point2f centre(80.0f, 80.0f);
  AffineTemplate patch;
  ASSERT_TRUE(patch.prepare(image, centre, WarpModel::kAffine, 15));
  cv::RNG random(5);
  const cv::Point2f truth(80.3f, 79.6f);
  const cv::Mat clean = warped(image, cv::Matx22f::eye(), centre, truth);
  // The spread of the errors about their mean (the sampling's own bias is the same every trial).
  const auto trials = [&](double noise) {
    double reported = 0.0;
    std::vector<cv::Point2f> found;
    for (int trial = 0; trial < 300; ++trial) {
      cv::Mat target;
      cv::Mat noisy;
      clean.convertTo(noisy, CV_32F);
      cv::Mat added(noisy.size(), CV_32F);
      random.fill(added, cv::RNG::NORMAL, 0.0, noise);
      cv::Mat sum = noisy + added;
      sum.convertTo(target, CV_8U);
      AffineWarp warp;
      warp.t = truth;
      if (!patch.align(target, warp, 15, 0.02)) continue;
      reported += warp.position_variance;
      found.push_back(warp.t);
    }
    EXPECT_GE(found.size(), 280u);
    cv::Point2f mean(0.0f, 0.0f);
    for (const cv::Point2f& t : found) mean += t;
    mean *= 1.0f / static_cast<float>(found.size());
    double spread = 0.0;
    for (const cv::Point2f& t : found)
      spread += 0.5 * (std::pow(t.x - mean.x, 2) + std::pow(t.y - mean.y, 2));
    return std::pair{reported / found.size(), spread / found.size()};
  };
  const auto [low_reported, low_error] = trials(3.0);
  const auto [high_reported, high_error] = trials(12.0);
  // Sixteen times the noise's variance: the reported variance grows about tenfold (the
  // sampling's own error is a floor), the errors' spread sixteenfold.
  EXPECT_GT(high_reported, 6.0 * low_reported);
  EXPECT_GT(high_error, 6.0 * low_error);
  // The errors' spread is the reported variance's up to a factor of one to three: the bilinear
  // sampling smooths the noise, which the residual then understates. The front-end scales the
  // variances to its tracks' own noise level (ObservationNoise) for that reason.
  for (const auto& [reported, error] :
       {std::pair{low_reported, low_error}, std::pair{high_reported, high_error}}) {
    EXPECT_GT(error, 1.0 * reported);
    EXPECT_LT(error, 3.0 * reported);
  }
}

}  // namespace
}  // namespace concord::frontend
