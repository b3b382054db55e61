#pragma once
/// \file
/// Private to the front-end: the coarse stereo search along an image row (block matching), which
/// gives KLT its starting disparity.

#include <opencv2/core.hpp>
#include <optional>

namespace concord::frontend {

/// Where a point of `from` lies along its row of `to`: the zero-mean sum of absolute differences
/// of a (2 radius + 1)^2 patch (radius at most 7), on images at `scale` (e.g. 0.5 for pyramid
/// level 1; the point is in full-resolution pixels), at offsets 0 to max_disparity
/// (full-resolution pixels) in the direction `sign`: -1 when the match lies to the left, as a
/// left-image point's in the right image of a rectified pair; +1 to the right (a right-image
/// point's in the left image). Returns the full-resolution offset of the best match, or nothing
/// when the patch does not fit in `from`. Both images 8-bit grey, of one size.
std::optional<float> search_row(const cv::Mat& from, const cv::Mat& to, const cv::Point2f& point,
                                float scale, int radius, double max_disparity, int sign);

}  // namespace concord::frontend
