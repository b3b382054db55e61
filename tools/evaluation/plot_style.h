#pragma once
// The look shared by the top-view plot (plot.cc) and the line charts (line_plot.cc): one font,
// one dash pattern, one legend row height and the same greys, so that the charts of a run match.

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace concord::evaluation::style {

inline constexpr int kFont = cv::FONT_HERSHEY_SIMPLEX;
inline constexpr int kLegendRowHeight = 24;
inline constexpr double kDashLength = 10.0;  // pixels drawn, then
inline constexpr double kDashGap = 7.0;      // pixels left out

inline const cv::Scalar kWhite(255, 255, 255);
inline const cv::Scalar kBlack(0, 0, 0);
inline const cv::Scalar kGridGrey(232, 232, 232);

}  // namespace concord::evaluation::style
