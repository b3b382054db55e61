#include "row_search.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <functional>
#include <limits>
#include <stdexcept>
#include <vector>

namespace concord::frontend {

std::optional<float> search_row(const cv::Mat& from, const cv::Mat& to, const cv::Point2f& point,
                                float scale, int radius, double max_disparity, int sign) {
  if (radius < 0 || radius > 7 || (sign != -1 && sign != 1) || from.size() != to.size() ||
      from.type() != CV_8UC1 || to.type() != CV_8UC1) {
    throw std::invalid_argument(
        "search_row: needs a radius of 0 to 7, a sign of -1 or +1 and two 8-bit grey images of "
        "one size");
  }
  const int x = cvRound(point.x * scale), y = cvRound(point.y * scale);
  if (x - radius < 0 || y - radius < 0 || x + radius >= from.cols || y + radius >= from.rows) {
    return std::nullopt;
  }
  const int side = 2 * radius + 1;
  std::array<int, 15 * 15> patch{};
  int sum = 0;
  for (int row = 0; row < side; ++row) {
    const unsigned char* pixels = from.ptr<unsigned char>(y - radius + row) + (x - radius);
    for (int column = 0; column < side; ++column) {
      patch[row * side + column] = pixels[column];
      sum += pixels[column];
    }
  }
  const int area = side * side;
  for (int index = 0; index < area; ++index) patch[index] = patch[index] * area - sum;
  // (The bound is applied before the conversion: a configured disparity beyond int stays defined.)
  const int room = sign < 0 ? x - radius : to.cols - 1 - radius - x;
  const int largest = static_cast<int>(std::min(max_disparity * scale, static_cast<double>(room)));
  if (largest < 0) return std::nullopt;
  // The window sums at every offset from the columns' sums over the window's rows (prefix sums
  // over the columns the windows cover).
  const int first_column = sign < 0 ? x - largest - radius : x - radius;
  const int columns = largest + side;
  thread_local std::vector<int> prefix;
  prefix.assign(static_cast<std::size_t>(columns) + 1, 0);
  for (int row = 0; row < side; ++row) {
    const unsigned char* pixels = to.ptr<unsigned char>(y - radius + row) + first_column;
    for (int column = 0; column < columns; ++column) prefix[column + 1] += pixels[column];
  }
  for (int column = 0; column < columns; ++column) prefix[column + 1] += prefix[column];
  int best_cost = std::numeric_limits<int>::max(), best_disparity = -1;
  for (int disparity = 0; disparity <= largest; ++disparity) {
    const int to_x = x + sign * disparity;
    const int window_sum = prefix[to_x + radius + 1 - first_column] - prefix[to_x - radius - first_column];
    int cost = 0;
    for (int row = 0; row < side && cost < best_cost; ++row) {
      const unsigned char* pixels = to.ptr<unsigned char>(y - radius + row) + (to_x - radius);
      for (int column = 0; column < side; ++column) {
        cost += std::abs(patch[row * side + column] - (pixels[column] * area - window_sum));
      }
    }
    if (cost < best_cost) {
      best_cost = cost;
      best_disparity = disparity;
    }
  }
  if (best_disparity < 0) return std::nullopt;
  return static_cast<float>(best_disparity) / scale;
}

cv::Mat scores_between(const cv::Mat& strip, const cv::Mat& templ, int lo, int hi) {
  constexpr int kDirectPositions = 16;
  cv::Mat scores;
  if (hi - lo + 1 > kDirectPositions || strip.type() != CV_8UC1 || templ.type() != CV_8UC1) {
    cv::matchTemplate(strip(cv::Rect(lo, 0, hi - lo + templ.cols, templ.rows)), templ, scores,
                      cv::TM_CCOEFF_NORMED);
    return scores;
  }
  const int rows = templ.rows, cols = templ.cols;
  const double count = static_cast<double>(rows) * cols;
  // The template without its mean, and its norm.
  cv::Mat centred;
  templ.convertTo(centred, CV_32F);
  const double mean = cv::mean(centred)[0];
  centred -= mean;
  const double template_norm = cv::norm(centred);
  scores.create(1, hi - lo + 1, CV_32F);
  for (int x = lo; x <= hi; ++x) {
    double dot = 0.0, sum = 0.0, squares = 0.0;
    for (int r = 0; r < rows; ++r) {
      const float* t = centred.ptr<float>(r);
      const std::uint8_t* image = strip.ptr<std::uint8_t>(r) + x;
      float row_dot = 0.0f;
      std::int32_t row_sum = 0, row_squares = 0;
      for (int c = 0; c < cols; ++c) {
        row_dot += t[c] * static_cast<float>(image[c]);
        row_sum += image[c];
        row_squares += image[c] * image[c];
      }
      dot += row_dot;
      sum += row_sum;
      squares += row_squares;
    }
    const double variance = squares - sum * sum / count;
    const double denominator = template_norm * std::sqrt(std::max(variance, 0.0));
    // cv::matchTemplate's rule: within rounding of +-1 is +-1, beyond it (a flat region) 0.
    double score = 0.0;
    if (std::abs(dot) < denominator) {
      score = dot / denominator;
    } else if (std::abs(dot) < 1.125 * denominator) {
      score = dot > 0.0 ? 1.0 : -1.0;
    }
    scores.at<float>(0, x - lo) = static_cast<float>(score);
  }
  return scores;
}

RowMatch match_along_row(const cv::Mat& strip, const cv::Mat& templ, int exclusion) {
  if (templ.empty() || strip.rows != templ.rows || strip.cols < templ.cols ||
      strip.type() != templ.type()) {
    throw std::invalid_argument(
        "match_along_row: needs a template no wider than the strip, of its height and type");
  }
  constexpr int kCoarseTemplate = 12;  // smaller templates (either side) are searched in full
  constexpr int kCoarsePositions = 24;
  constexpr int kCandidates = 3;  // coarse peaks scored at full resolution
  constexpr int kRefine = 3;      // full-resolution positions either side of a coarse peak
  const int positions = strip.cols - templ.cols + 1;
  RowMatch match;
  const auto peak_of = [&](const cv::Mat& scores, int lo) {
    double best = -2.0;
    int at = 0;
    for (int x = 0; x < scores.cols; ++x) {
      if (scores.at<float>(0, x) > best) {
        best = scores.at<float>(0, x);
        at = x;
      }
    }
    RowMatch peak;
    peak.x = lo + at;
    peak.score = best;
    if (at > 0) peak.before = scores.at<float>(0, at - 1);
    if (at + 1 < scores.cols) peak.after = scores.at<float>(0, at + 1);
    return peak;
  };
  if (templ.cols < kCoarseTemplate || templ.rows < kCoarseTemplate ||
      positions < kCoarsePositions) {
    const cv::Mat scores = scores_between(strip, templ, 0, positions - 1);
    match = peak_of(scores, 0);
    for (int x = 0; x < scores.cols; ++x) {
      if (std::abs(x - match.x) > exclusion) {
        match.second = std::max(match.second, static_cast<double>(scores.at<float>(0, x)));
      }
    }
    return match;
  }
  cv::Mat strip_coarse, templ_coarse, coarse;
  cv::pyrDown(strip, strip_coarse);
  cv::pyrDown(templ, templ_coarse);
  cv::matchTemplate(strip_coarse, templ_coarse, coarse, cv::TM_CCOEFF_NORMED);
  // The coarse peaks, best first, each more than half the exclusion from a better one.
  std::vector<std::pair<float, int>> peaks;
  for (int x = 0; x < coarse.cols; ++x) {
    const float value = coarse.at<float>(0, x);
    if ((x == 0 || value >= coarse.at<float>(0, x - 1)) &&
        (x + 1 == coarse.cols || value >= coarse.at<float>(0, x + 1))) {
      peaks.emplace_back(value, x);
    }
  }
  std::sort(peaks.begin(), peaks.end(), std::greater<>());
  const int coarse_exclusion = std::max(1, exclusion / 2);
  std::vector<RowMatch> refined;
  for (const auto& peak_entry : peaks) {
    const int x = peak_entry.second;  // a variable: clang 14 cannot capture a structured binding
    if (static_cast<int>(refined.size()) == kCandidates) break;
    const bool apart = std::all_of(refined.begin(), refined.end(), [&](const RowMatch& other) {
      return std::abs(2 * x - other.x) > 2 * coarse_exclusion;
    });
    if (!apart) continue;
    const int lo = std::clamp(2 * x - kRefine, 0, positions - 1);
    const int hi = std::clamp(2 * x + kRefine, 0, positions - 1);
    RowMatch peak = peak_of(scores_between(strip, templ, lo, hi), lo);
    // A peak at the edge of its window (not of the strip) is scored one step further out.
    if ((peak.x == lo && lo > 0) || (peak.x == hi && hi < positions - 1)) {
      const int from = std::max(0, peak.x - 1), to = std::min(positions - 1, peak.x + 1);
      peak = peak_of(scores_between(strip, templ, from, to), from);
    }
    refined.push_back(peak);
  }
  std::sort(refined.begin(), refined.end(),
            [](const RowMatch& a, const RowMatch& b) { return a.score > b.score; });
  match = refined.front();
  for (std::size_t k = 1; k < refined.size(); ++k) {
    if (std::abs(refined[k].x - match.x) > exclusion) {
      match.second = std::max(match.second, refined[k].score);
    }
  }
  return match;
}

}  // namespace concord::frontend
