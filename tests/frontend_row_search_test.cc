// The coarse stereo search along a row (frontend/src/row_search.h), on a random texture and a
// copy of it shifted by a known disparity: the disparity found in both directions, at full and
// half resolution, whatever the brightness offset; the limits and the refused arguments.
#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgproc.hpp>
#include <utility>

#include "frontend_test_support.h"
#include "row_search.h"

namespace concord::frontend {
namespace {

/// A textured left image and its right image: every point at column x of the left image is at
/// column x - disparity of the right one, brightened by `offset`.
struct Pair {
  cv::Mat left, right;
};
Pair shifted_pair(int disparity, int offset) {
  Pair pair;
  pair.left = testing::random_texture(cv::Size(320, 120), 5);
  cv::normalize(pair.left, pair.left, 20.0, 200.0, cv::NORM_MINMAX);
  const cv::Matx23f shift(1, 0, static_cast<float>(-disparity), 0, 1, 0);
  cv::warpAffine(pair.left, pair.right, cv::Mat(shift), pair.left.size(), cv::INTER_NEAREST,
                 cv::BORDER_REFLECT_101);
  pair.right += cv::Scalar(offset);
  return pair;
}

TEST(RowSearch, FindsAKnownDisparityFromEitherImage) {
  for (const int offset : {0, 30}) {
    const Pair pair = shifted_pair(24, offset);
    for (const cv::Point2f left : {cv::Point2f(200.0f, 60.0f), cv::Point2f(120.0f, 30.0f)}) {
      const auto forward = search_row(pair.left, pair.right, left, 1.0f, 4, 64.0, -1);
      ASSERT_TRUE(forward.has_value());
      EXPECT_FLOAT_EQ(*forward, 24.0f) << "offset " << offset;
      // From the right image's point, the match lies to the right in the left image.
      const auto back =
          search_row(pair.right, pair.left, left - cv::Point2f(24.0f, 0.0f), 1.0f, 4, 64.0, +1);
      ASSERT_TRUE(back.has_value());
      EXPECT_FLOAT_EQ(*back, 24.0f) << "offset " << offset;
      // Searched the wrong way, the true disparity is not among the offsets tried.
      const auto wrong_way = search_row(pair.left, pair.right, left, 1.0f, 4, 64.0, +1);
      ASSERT_TRUE(wrong_way.has_value());
      EXPECT_NE(*wrong_way, 24.0f);
    }
  }
}

TEST(RowSearch, AtHalfResolutionReturnsFullResolutionPixels) {
  const Pair pair = shifted_pair(40, 0);
  cv::Mat left_half, right_half;
  cv::pyrDown(pair.left, left_half);
  cv::pyrDown(pair.right, right_half);
  const cv::Point2f left(220.0f, 60.0f);  // full-resolution pixels
  const auto forward = search_row(left_half, right_half, left, 0.5f, 4, 100.0, -1);
  ASSERT_TRUE(forward.has_value());
  EXPECT_NEAR(*forward, 40.0f, 2.0f);  // one pixel at half resolution
  const auto back = search_row(right_half, left_half, left - cv::Point2f(*forward, 0.0f), 0.5f, 4,
                               100.0, +1);
  ASSERT_TRUE(back.has_value());
  EXPECT_NEAR(*back, *forward, 2.0f);
}

TEST(RowSearch, StaysWithinTheImageAndTheLargestDisparity) {
  const Pair pair = shifted_pair(24, 0);
  // The patch must fit around the point.
  EXPECT_FALSE(search_row(pair.left, pair.right, cv::Point2f(2.0f, 60.0f), 1.0f, 4, 64.0, -1));
  EXPECT_FALSE(search_row(pair.left, pair.right, cv::Point2f(200.0f, 118.0f), 1.0f, 4, 64.0, -1));
  // Near the left border only the offsets that keep the window inside are tried.
  const auto near_border = search_row(pair.left, pair.right, cv::Point2f(14.0f, 60.0f), 1.0f, 4,
                                      64.0, -1);
  ASSERT_TRUE(near_border.has_value());
  EXPECT_LE(*near_border, 10.0f);
  // Near the right border, searching to the right likewise.
  const auto near_right = search_row(pair.right, pair.left, cv::Point2f(310.0f, 60.0f), 1.0f, 4,
                                     64.0, +1);
  ASSERT_TRUE(near_right.has_value());
  EXPECT_LE(*near_right, 5.0f);
  // A disparity beyond the largest searched is not found.
  const auto capped = search_row(pair.left, pair.right, cv::Point2f(200.0f, 60.0f), 1.0f, 4, 16.0, -1);
  ASSERT_TRUE(capped.has_value());
  EXPECT_LE(*capped, 16.0f);
}

TEST(RowSearch, RefusesArgumentsItCannotUse) {
  const Pair pair = shifted_pair(24, 0);
  const cv::Point2f point(200.0f, 60.0f);
  EXPECT_THROW(search_row(pair.left, pair.right, point, 1.0f, 8, 64.0, -1), std::invalid_argument);
  EXPECT_THROW(search_row(pair.left, pair.right, point, 1.0f, 4, 64.0, 0), std::invalid_argument);
  cv::Mat smaller = pair.right(cv::Rect(0, 0, 300, 120)).clone();
  EXPECT_THROW(search_row(pair.left, smaller, point, 1.0f, 4, 64.0, -1), std::invalid_argument);
  cv::Mat colour;
  cv::cvtColor(pair.right, colour, cv::COLOR_GRAY2BGR);
  EXPECT_THROW(search_row(pair.left, colour, point, 1.0f, 4, 64.0, -1), std::invalid_argument);
}

// The object matcher's scores (row_search.h, scores_between): a few positions scored directly are
// cv::matchTemplate's, flat regions included; many positions are cv::matchTemplate's own.
TEST(RowMatch, ScoresOfAFewPositionsAreThoseOfMatchTemplate) {
  const Pair pair = shifted_pair(24, 30);
  const cv::Mat strip = pair.right(cv::Rect(40, 30, 200, 40));
  const cv::Mat templ = pair.left(cv::Rect(150, 30, 40, 40));
  cv::Mat reference;
  cv::matchTemplate(strip, templ, reference, cv::TM_CCOEFF_NORMED);
  for (const auto& [lo, hi] : {std::pair{0, 6}, std::pair{80, 95}, std::pair{150, 160},
                                std::pair{0, 160}}) {
    const cv::Mat scores = scores_between(strip, templ, lo, hi);
    ASSERT_EQ(scores.cols, hi - lo + 1);
    for (int x = lo; x <= hi; ++x) {
      EXPECT_NEAR(scores.at<float>(0, x - lo), reference.at<float>(0, x), 1e-4) << "at " << x;
    }
  }
  // A flat template, or a flat region of the strip, scores 0 (as cv::matchTemplate).
  cv::Mat flat_strip = strip.clone();
  flat_strip(cv::Rect(100, 0, 60, 40)).setTo(90);
  cv::matchTemplate(flat_strip, templ, reference, cv::TM_CCOEFF_NORMED);
  const cv::Mat flat_scores = scores_between(flat_strip, templ, 105, 115);
  for (int x = 105; x <= 115; ++x) {
    EXPECT_NEAR(flat_scores.at<float>(0, x - 105), reference.at<float>(0, x), 1e-4);
  }
  EXPECT_EQ(flat_scores.at<float>(0, 10), 0.0f);
  const cv::Mat flat_template(40, 40, CV_8UC1, cv::Scalar(90));
  EXPECT_EQ(scores_between(strip, flat_template, 10, 12).at<float>(0, 1), 0.0f);
}

// Coarse to fine: the match of a region along its row at every shift parity and template size
// (small templates are searched in full), to the pixel; a repeated copy is the rival.
TEST(RowMatch, FindsTheShiftAndReportsARepeatedCopyAsTheRival) {
  for (const int disparity : {23, 24, 57}) {
    const Pair pair = shifted_pair(disparity, 0);
    for (const int side : {8, 20, 41}) {
      const cv::Rect region(230, 40, side, side);
      const int start = 100;
      const cv::Rect strip(start, region.y, region.x + region.width - start, region.height);
      const RowMatch match =
          match_along_row(pair.right(strip), pair.left(region), std::max(2, side / 2));
      EXPECT_EQ(start + match.x, region.x - disparity) << "side " << side;
      EXPECT_GT(match.score, 0.99);
      EXPECT_LT(match.second, 0.9 * match.score) << "side " << side;
      ASSERT_TRUE(std::isfinite(match.before) && std::isfinite(match.after));
      EXPECT_LT(match.before, match.score);
      EXPECT_LT(match.after, match.score);
    }
  }
  // The region again 80 px further along the row: the best and the rival score alike.
  Pair pair = shifted_pair(24, 0);
  const cv::Rect region(230, 40, 30, 30);
  pair.left(region).copyTo(pair.right(cv::Rect(region.x - 24 - 80, region.y, 30, 30)));
  const cv::Rect strip(60, region.y, region.x + region.width - 60, region.height);
  const RowMatch repeated = match_along_row(pair.right(strip), pair.left(region), 15);
  EXPECT_GT(repeated.second, 0.99);
  const int found = strip.x + repeated.x;
  EXPECT_TRUE(found == region.x - 24 || found == region.x - 104) << found;
  EXPECT_THROW(match_along_row(pair.left(region), pair.right(strip), 15), std::invalid_argument);
}

}  // namespace
}  // namespace concord::frontend
