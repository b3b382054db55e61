#include "evaluation/plot.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "concord/estimator/updater_helper.h"
#include "evaluation/plot_style.h"

namespace concord::evaluation {
namespace {

using namespace style;

// Layout in pixels: the title on top, the plot on the left, the legend in a column on the right.
constexpr int kTitleBaseline = 40;
constexpr int kPlotLeft = 80;
constexpr int kPlotTop = 70;
constexpr int kLegendWidth = 280;
constexpr int kPlotRight = kTopViewWidth - kLegendWidth - 20;
constexpr int kPlotBottom = kTopViewHeight - 60;
constexpr int kLegendLeft = kTopViewWidth - kLegendWidth;

const cv::Scalar kTextGrey(90, 90, 90);

/// Distinct colours (BGR) for the first robots; more robots get hues spread by the golden ratio.
cv::Scalar robot_colour(std::size_t robot) {
  static const std::array<cv::Scalar, 16> palette = {
      cv::Scalar(180, 119, 31),  cv::Scalar(14, 127, 255),  cv::Scalar(44, 160, 44),
      cv::Scalar(40, 39, 214),   cv::Scalar(189, 103, 148), cv::Scalar(75, 86, 140),
      cv::Scalar(194, 119, 227), cv::Scalar(34, 189, 188),  cv::Scalar(207, 190, 23),
      cv::Scalar(128, 0, 0),     cv::Scalar(128, 128, 0),   cv::Scalar(32, 165, 218),
      cv::Scalar(139, 0, 139),   cv::Scalar(237, 149, 100), cv::Scalar(0, 0, 128),
      cv::Scalar(50, 205, 50),
  };
  if (robot < palette.size()) return palette[robot];
  const double hue = std::fmod(static_cast<double>(robot) * 0.618033988749895, 1.0);
  cv::Mat hsv(1, 1, CV_8UC3, cv::Scalar(hue * 180.0, 220, 200));
  cv::Mat bgr;
  cv::cvtColor(hsv, bgr, cv::COLOR_HSV2BGR);
  const cv::Vec3b pixel = bgr.at<cv::Vec3b>(0, 0);
  return cv::Scalar(pixel[0], pixel[1], pixel[2]);
}

/// The robot colour washed towards light grey, for ground truth.
cv::Scalar groundtruth_tint(const cv::Scalar& colour) {
  constexpr double kColourShare = 0.4;
  constexpr double kGrey = 185.0;
  return colour * kColourShare + cv::Scalar::all(kGrey * (1.0 - kColourShare));
}

/// An axis-aligned box in world x-y.
struct Bounds {
  double min_x = std::numeric_limits<double>::infinity();
  double min_y = std::numeric_limits<double>::infinity();
  double max_x = -std::numeric_limits<double>::infinity();
  double max_y = -std::numeric_limits<double>::infinity();

  bool empty() const { return !(min_x <= max_x && min_y <= max_y); }
  double width() const { return max_x - min_x; }
  double height() const { return max_y - min_y; }
  void add(const Eigen::Vector2d& point) {
    if (!point.allFinite()) return;
    min_x = std::min(min_x, point.x());
    min_y = std::min(min_y, point.y());
    max_x = std::max(max_x, point.x());
    max_y = std::max(max_y, point.y());
  }
};

/// Everything drawn for one robot, in world x-y.
struct RobotPaths {
  std::vector<Eigen::Vector2d> groundtruth;
  std::vector<Eigen::Vector2d> odometry;
  std::vector<Eigen::Vector2d> estimate;
  std::vector<Eigen::Vector2d> objects;
};

std::vector<Eigen::Vector2d> top_view(const std::vector<Eigen::Isometry3d>& poses) {
  std::vector<Eigen::Vector2d> points;
  points.reserve(poses.size());
  for (const Eigen::Isometry3d& T_world_body : poses) {
    points.push_back(T_world_body.translation().head<2>());
  }
  return points;
}

/// The view: ground truth and true objects, widened to take in estimates that stray by up to half
/// that extent on each side, plus a small pad.
Bounds view_bounds(const std::vector<RobotPaths>& robots,
                   const std::map<LandmarkId, Eigen::Vector3d>& objects_groundtruth) {
  Bounds truth;
  for (const RobotPaths& robot : robots) {
    for (const Eigen::Vector2d& point : robot.groundtruth) truth.add(point);
  }
  for (const auto& [id, p_world] : objects_groundtruth) truth.add(p_world.head<2>());

  Bounds everything = truth;
  for (const RobotPaths& robot : robots) {
    for (const auto* points : {&robot.odometry, &robot.estimate, &robot.objects}) {
      for (const Eigen::Vector2d& point : *points) everything.add(point);
    }
  }
  if (everything.empty()) everything.add(Eigen::Vector2d::Zero());

  Bounds view = everything;
  if (!truth.empty()) {
    const double allowance = 0.5 * std::max({truth.width(), truth.height(), 1.0});
    view.min_x = std::max(view.min_x, truth.min_x - allowance);
    view.min_y = std::max(view.min_y, truth.min_y - allowance);
    view.max_x = std::min(view.max_x, truth.max_x + allowance);
    view.max_y = std::min(view.max_y, truth.max_y + allowance);
  }
  const double pad = 0.03 * std::max({view.width(), view.height(), 1.0});
  view.min_x -= pad;
  view.min_y -= pad;
  view.max_x += pad;
  view.max_y += pad;
  return view;
}

/// World x-y to pixels of the plot area, equal scale on both axes, y up.
class WorldToPixel {
 public:
  WorldToPixel(const Bounds& view, int width, int height)
      : width_(width),
        height_(height),
        centre_(0.5 * (view.min_x + view.max_x), 0.5 * (view.min_y + view.max_y)),
        pixels_per_metre_(std::min(width / view.width(), height / view.height())) {}

  cv::Point operator()(const Eigen::Vector2d& point) const {
    // Clamped far outside the image so that integer conversion cannot overflow; drawing clips.
    constexpr double kLimit = 1.0e5;
    const double column = 0.5 * width_ + (point.x() - centre_.x()) * pixels_per_metre_;
    const double row = 0.5 * height_ - (point.y() - centre_.y()) * pixels_per_metre_;
    return {static_cast<int>(std::lround(std::clamp(column, -kLimit, kLimit))),
            static_cast<int>(std::lround(std::clamp(row, -kLimit, kLimit)))};
  }

  double pixels_per_metre() const { return pixels_per_metre_; }
  /// World coordinate of a pixel column / row.
  double world_x(double column) const {
    return centre_.x() + (column - 0.5 * width_) / pixels_per_metre_;
  }
  double world_y(double row) const {
    return centre_.y() - (row - 0.5 * height_) / pixels_per_metre_;
  }

 private:
  int width_;
  int height_;
  Eigen::Vector2d centre_;
  double pixels_per_metre_;
};

/// Finite points as pixels, without consecutive repeats.
std::vector<cv::Point> to_pixels(const std::vector<Eigen::Vector2d>& points,
                                 const WorldToPixel& world_to_pixel) {
  std::vector<cv::Point> pixels;
  pixels.reserve(points.size());
  for (const Eigen::Vector2d& point : points) {
    if (!point.allFinite()) continue;
    const cv::Point pixel = world_to_pixel(point);
    if (pixels.empty() || pixels.back() != pixel) pixels.push_back(pixel);
  }
  return pixels;
}

void draw_solid(cv::Mat& canvas, const std::vector<cv::Point>& pixels, const cv::Scalar& colour,
                int thickness) {
  if (pixels.size() < 2) return;
  cv::polylines(canvas, pixels, false, colour, thickness, cv::LINE_AA);
}

/// A dashed polyline; the dash pattern runs on across vertices.
void draw_dashed(cv::Mat& canvas, const std::vector<cv::Point>& pixels, const cv::Scalar& colour,
                 int thickness) {
  double phase = 0.0;  // distance into the current dash + gap period
  const double period = kDashLength + kDashGap;
  for (std::size_t i = 1; i < pixels.size(); ++i) {
    const cv::Point2d from = pixels[i - 1];
    const cv::Point2d to = pixels[i];
    const double length = cv::norm(to - from);
    double travelled = 0.0;
    while (travelled < length) {
      const bool in_dash = phase < kDashLength;
      const double step =
          std::min(length - travelled, in_dash ? kDashLength - phase : period - phase);
      if (in_dash) {
        const cv::Point2d start = from + (to - from) * (travelled / length);
        const cv::Point2d end = from + (to - from) * ((travelled + step) / length);
        cv::line(canvas, cv::Point(cvRound(start.x), cvRound(start.y)),
                 cv::Point(cvRound(end.x), cvRound(end.y)), colour, thickness, cv::LINE_AA);
      }
      travelled += step;
      phase = std::fmod(phase + step, period);
    }
  }
}

/// 1, 2 or 5 times a power of ten, at least `target`.
double round_length(double target) {
  const double power = std::pow(10.0, std::floor(std::log10(target)));
  for (const double factor : {1.0, 2.0, 5.0}) {
    if (factor * power >= target) return factor * power;
  }
  return 10.0 * power;
}

std::string metres_label(double metres) {
  char text[32];
  std::snprintf(text, sizeof(text), "%g", metres);
  return text;
}

/// Light grid lines every `spacing` metres, labelled on the left and bottom edges.
void draw_grid(cv::Mat& image, const cv::Rect& plot_area, const WorldToPixel& world_to_pixel,
               double spacing) {
  cv::Mat plot = image(plot_area);
  // Lines at whole multiples of the spacing (an index, not a running sum, so labels stay exact).
  const long first_column_line = std::lround(std::ceil(world_to_pixel.world_x(0) / spacing));
  const long last_column_line =
      std::lround(std::floor(world_to_pixel.world_x(plot_area.width) / spacing));
  for (long line = first_column_line; line <= last_column_line; ++line) {
    const double x = static_cast<double>(line) * spacing;
    const int column = world_to_pixel(Eigen::Vector2d(x, 0.0)).x;
    cv::line(plot, {column, 0}, {column, plot_area.height}, kGridGrey, 1);
    cv::putText(image, metres_label(x), {plot_area.x + column - 15, plot_area.br().y + 20}, kFont,
                0.4, kTextGrey, 1, cv::LINE_AA);
  }
  const long first_row_line =
      std::lround(std::ceil(world_to_pixel.world_y(plot_area.height) / spacing));
  const long last_row_line = std::lround(std::floor(world_to_pixel.world_y(0) / spacing));
  for (long line = first_row_line; line <= last_row_line; ++line) {
    const double y = static_cast<double>(line) * spacing;
    const int row = world_to_pixel(Eigen::Vector2d(0.0, y)).y;
    cv::line(plot, {0, row}, {plot_area.width, row}, kGridGrey, 1);
    cv::putText(image, metres_label(y), {5, plot_area.y + row + 5}, kFont, 0.4, kTextGrey, 1,
                cv::LINE_AA);
  }
  cv::putText(image, "x [m]", {plot_area.x + plot_area.width / 2 - 20, plot_area.br().y + 45},
              kFont, 0.5, kTextGrey, 1, cv::LINE_AA);
  cv::putText(image, "y [m]", {5, plot_area.y - 10}, kFont, 0.5, kTextGrey, 1, cv::LINE_AA);
  cv::rectangle(image, plot_area, kTextGrey, 1);
}

/// A bar of `length` metres starting at `left`, labelled above.
void draw_scale_bar(cv::Mat& image, const cv::Point& left, double length, double pixels_per_metre) {
  const int bar_pixels = static_cast<int>(std::lround(length * pixels_per_metre));
  const cv::Point right(left.x + bar_pixels, left.y);
  cv::line(image, left, right, kBlack, 3);
  cv::line(image, left + cv::Point(0, -7), left + cv::Point(0, 7), kBlack, 2);
  cv::line(image, right + cv::Point(0, -7), right + cv::Point(0, 7), kBlack, 2);
  cv::putText(image, "scale " + metres_label(length) + " m", {left.x, left.y - 14}, kFont, 0.5,
              kBlack, 1, cv::LINE_AA);
}

void draw_true_object(cv::Mat& canvas, const cv::Point& pixel) {
  cv::drawMarker(canvas, pixel, kBlack, cv::MARKER_CROSS, 9, 1, cv::LINE_AA);
}

void draw_estimated_object(cv::Mat& canvas, const cv::Point& pixel, const cv::Scalar& colour) {
  cv::circle(canvas, pixel, 3, colour, cv::FILLED, cv::LINE_AA);
}

/// Robot colours, the line and marker styles, then a scale bar of `scale_length` metres.
void draw_legend(cv::Mat& image, std::size_t robot_count, double scale_length,
                 double pixels_per_metre) {
  const int swatch_left = kLegendLeft + 10;
  const int swatch_right = swatch_left + 40;
  const int text_left = swatch_right + 12;
  int baseline = kPlotTop + 10;
  const auto label = [&](const std::string& text) {
    cv::putText(image, text, {text_left, baseline + 5}, kFont, 0.5, kBlack, 1, cv::LINE_AA);
    baseline += kLegendRowHeight;
  };
  const cv::Point swatch_start(swatch_left, 0);
  const cv::Point swatch_end(swatch_right, 0);

  constexpr int kStyleAndScaleRows = 9;
  const int rows_available = (kPlotBottom - kPlotTop) / kLegendRowHeight - kStyleAndScaleRows;
  const std::size_t robots_listed =
      std::min<std::size_t>(robot_count, static_cast<std::size_t>(std::max(rows_available, 1)));
  for (std::size_t robot = 0; robot < robots_listed; ++robot) {
    const cv::Point row(0, baseline);
    cv::line(image, swatch_start + row, swatch_end + row, robot_colour(robot), 4, cv::LINE_AA);
    label("robot " + std::to_string(robot));
  }
  if (robots_listed < robot_count) {
    label("... " + std::to_string(robot_count - robots_listed) + " more robots");
  }

  baseline += kLegendRowHeight / 2;
  const cv::Scalar example = robot_colour(0);
  cv::line(image, swatch_start + cv::Point(0, baseline), swatch_end + cv::Point(0, baseline),
           groundtruth_tint(example), 2, cv::LINE_AA);
  label("ground truth");
  draw_dashed(image, {swatch_start + cv::Point(0, baseline), swatch_end + cv::Point(0, baseline)},
              example, 1);
  label("odometry only");
  cv::line(image, swatch_start + cv::Point(0, baseline), swatch_end + cv::Point(0, baseline),
           example, 3, cv::LINE_AA);
  label("estimate");
  draw_true_object(image, {(swatch_left + swatch_right) / 2, baseline});
  label("true object");
  draw_estimated_object(image, {(swatch_left + swatch_right) / 2, baseline}, example);
  label("estimated object");

  baseline += 2 * kLegendRowHeight;
  draw_scale_bar(image, {swatch_left, baseline}, scale_length, pixels_per_metre);
}

}  // namespace

void write_top_view_png(const std::filesystem::path& file, const std::vector<RobotTruth>& truths,
                        const std::vector<RobotResult>& results,
                        const std::map<LandmarkId, Eigen::Vector3d>& objects_groundtruth,
                        const std::string& title) {
  if (truths.size() != results.size()) {
    throw std::invalid_argument(
        "top view needs one result per robot: " + std::to_string(truths.size()) +
        " ground truths, " + std::to_string(results.size()) + " results");
  }

  // 1. Everything to draw, in world x-y.
  std::vector<RobotPaths> robots(truths.size());
  for (std::size_t robot = 0; robot < truths.size(); ++robot) {
    const RobotTruth& truth = truths[robot];
    robots[robot].groundtruth = top_view(truth.groundtruth);
    if (!truth.groundtruth.empty() && !truth.odometry.empty()) {
      robots[robot].odometry = top_view(dead_reckoning(truth.groundtruth.front(), truth.odometry));
    }
    robots[robot].estimate = top_view(results[robot].trajectory);
    for (const ObjectEstimate& object : results[robot].objects) {
      robots[robot].objects.push_back(object.p_world.head<2>());
    }
  }

  // 2. The view at equal scale and a grid of a round spacing (also the scale bar's length).
  cv::Mat image(kTopViewHeight, kTopViewWidth, CV_8UC3, kWhite);
  const cv::Rect plot_area(kPlotLeft, kPlotTop, kPlotRight - kPlotLeft, kPlotBottom - kPlotTop);
  const WorldToPixel world_to_pixel(view_bounds(robots, objects_groundtruth), plot_area.width,
                                    plot_area.height);
  const double grid_spacing = round_length(100.0 / world_to_pixel.pixels_per_metre());
  draw_grid(image, plot_area, world_to_pixel, grid_spacing);

  // 3. Trajectories, drawn into the plot area only (the sub-image clips them): ground truth under
  // odometry under estimates.
  cv::Mat plot = image(plot_area);
  for (std::size_t robot = 0; robot < robots.size(); ++robot) {
    draw_solid(plot, to_pixels(robots[robot].groundtruth, world_to_pixel),
               groundtruth_tint(robot_colour(robot)), 2);
  }
  for (std::size_t robot = 0; robot < robots.size(); ++robot) {
    draw_dashed(plot, to_pixels(robots[robot].odometry, world_to_pixel), robot_colour(robot), 1);
  }
  for (std::size_t robot = 0; robot < robots.size(); ++robot) {
    draw_solid(plot, to_pixels(robots[robot].estimate, world_to_pixel), robot_colour(robot), 3);
  }

  // 4. Objects on top: estimated dots, then true crosses.
  for (std::size_t robot = 0; robot < robots.size(); ++robot) {
    for (const cv::Point& pixel : to_pixels(robots[robot].objects, world_to_pixel)) {
      draw_estimated_object(plot, pixel, robot_colour(robot));
    }
  }
  for (const auto& [id, p_world] : objects_groundtruth) {
    if (p_world.allFinite()) draw_true_object(plot, world_to_pixel(p_world.head<2>()));
  }

  // 5. Title, legend and scale bar.
  cv::putText(image, title, {kPlotLeft, kTitleBaseline}, kFont, 0.8, kBlack, 2, cv::LINE_AA);
  draw_legend(image, robots.size(), grid_spacing, world_to_pixel.pixels_per_metre());

  bool written = false;
  try {
    written = cv::imwrite(file.string(), image);
  } catch (const cv::Exception& error) {
    throw std::runtime_error("cannot write top view " + file.string() + ": " + error.what());
  }
  if (!written) throw std::runtime_error("cannot write top view " + file.string());
}

std::optional<LinePlot> pose_nees_plot(const std::vector<RobotTruth>& truths,
                                       const std::vector<RobotResult>& results, int window,
                                       const std::string& title) {
  if (truths.size() != results.size()) {
    throw std::invalid_argument("pose_nees_plot: " + std::to_string(truths.size()) +
                                " ground truths, " + std::to_string(results.size()) + " results");
  }
  window = std::max(window, 1);
  std::vector<std::vector<double>> series;
  std::size_t frames = 0;
  for (std::size_t robot = 0; robot < results.size(); ++robot) {
    series.push_back(pose_nees_series(truths[robot], results[robot]));
    frames = std::max(frames, series.back().size());
  }
  // 1. Per frame: the median over robots.
  std::vector<double> median(frames, std::numeric_limits<double>::quiet_NaN());
  for (std::size_t frame = 0; frame < frames; ++frame) {
    std::vector<double> values;
    for (const auto& robot : series) {
      if (frame < robot.size() && std::isfinite(robot[frame])) values.push_back(robot[frame]);
    }
    if (values.empty()) continue;
    std::sort(values.begin(), values.end());
    const std::size_t middle = values.size() / 2;
    median[frame] = values.size() % 2 == 1 ? values[middle]
                                           : 0.5 * (values[middle - 1] + values[middle]);
  }
  // 2. Window means.
  LineSeries nees{"pose NEES (median over robots)", {}, {}, false, false, 0};
  for (std::size_t start = 0; start < frames; start += static_cast<std::size_t>(window)) {
    const std::size_t end = std::min(frames, start + static_cast<std::size_t>(window));
    double sum = 0.0;
    int count = 0;
    for (std::size_t frame = start; frame < end; ++frame) {
      if (std::isnan(median[frame])) continue;
      sum += median[frame];
      ++count;
    }
    if (count == 0) continue;
    nees.x.push_back(0.5 * static_cast<double>(start + end - 1));
    nees.y.push_back(sum / count);
  }
  if (nees.x.empty()) return std::nullopt;
  const double first = nees.x.front();
  const double last = nees.x.back() > first ? nees.x.back() : first + 1.0;
  const double bound = UpdaterHelper::chi2_quantile(0.95, 6);
  LinePlot plot;
  plot.title = title;
  plot.x_label = "frame";
  plot.y_label = "pose NEES (6-D)";
  plot.y_min = 0.0;
  plot.series.push_back(std::move(nees));
  plot.series.push_back({"expected (6)", {first, last}, {6.0, 6.0}, true, false, 1});
  plot.series.push_back({"95 % bound", {first, last}, {bound, bound}, true, false, 2});
  return plot;
}

}  // namespace concord::evaluation
