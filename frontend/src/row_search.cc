#include "row_search.h"

#include <algorithm>
#include <array>
#include <cstdlib>
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

}  // namespace concord::frontend
