#pragma once
/// \file
/// Private to the front-end: searches along an image row. The coarse stereo search (block
/// matching), which gives KLT its starting disparity, and the template match of an object's
/// region (normalized cross-correlation, coarse to fine).

#include <opencv2/core.hpp>
#include <limits>
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

/// The best match of `templ` along `strip` (both of one height): its position (the template's
/// left column in the strip), normalized cross-correlation score and the scores one position
/// either side (NaN at the strip's ends), and the best score of another peak more than
/// `exclusion` positions away (-1 if none).
struct RowMatch {
  int x = 0;
  double score = -1.0;
  double before = std::numeric_limits<double>::quiet_NaN();
  double after = std::numeric_limits<double>::quiet_NaN();
  double second = -1.0;
};

/// Normalized cross-correlation (cv::TM_CCOEFF_NORMED) of `templ` at positions lo..hi
/// (inclusive; the template's left column) of `strip`, both of one height: one row of hi - lo + 1
/// scores. A few positions of 8-bit images are scored directly (cv::matchTemplate correlates by
/// DFT, whose set-up costs far more than a few sums), with cv::matchTemplate's rule for flat
/// regions.
cv::Mat scores_between(const cv::Mat& strip, const cv::Mat& templ, int lo, int hi);

/// The best match of `templ` along `strip`, coarse to fine: searched at every position at half
/// resolution (both Gaussian-filtered and decimated, cv::pyrDown), then the best few coarse
/// peaks (local maxima more than half of `exclusion` apart) are scored at full resolution a few
/// pixels around their position; the best full-resolution peak is the match and the best of the
/// others more than `exclusion` from it its rival (`second`). Small templates or searches are
/// scored at every full-resolution position.
RowMatch match_along_row(const cv::Mat& strip, const cv::Mat& templ, int exclusion);

}  // namespace concord::frontend
