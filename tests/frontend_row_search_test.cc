// The coarse stereo search along a row (frontend/src/row_search.h), on a random texture and a
// copy of it shifted by a known disparity: the disparity found in both directions, at full and
// half resolution, whatever the brightness offset; the limits and the refused arguments.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

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

}  // namespace
}  // namespace concord::frontend
