#include "evaluation/line_plot.h"

#include <algorithm>
#include <array>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>

#include "concord/dataset/result_io.h"
#include "evaluation/plot_style.h"

namespace concord::evaluation {
namespace {

using namespace style;

// Layout in pixels: the title on top, the y label (turned) and tick labels on the left, the
// x tick labels and x label below, the legend in a column right of the plot area.
constexpr int kOuterMargin = 12;
constexpr int kTickLength = 5;
constexpr int kTickLabelGap = 4;
constexpr int kLabelGap = 10;
constexpr int kLegendPadding = 10;
constexpr int kLegendSwatchLength = 40;
constexpr double kLegendMaxWidthShare = 0.4;  // of the image width
constexpr int kMinimumPlotSide = 20;
// Pixels per tick interval at most, so that tick labels do not crowd.
constexpr int kMinimumColumnsPerXTick = 90;
constexpr int kMinimumRowsPerYTick = 40;
constexpr int kMinimumTickIntervals = 5;
constexpr int kTickLabelSpacing = 10;

constexpr double kDataMargin = 0.05;  // of the data span, on each side
constexpr int kLineThickness = 2;
constexpr int kMarkerRadius = 4;

constexpr double kTitleScale = 0.7;
constexpr int kTitleThickness = 2;
constexpr double kAxisLabelScale = 0.55;
constexpr double kTickLabelScale = 0.45;
constexpr double kLegendScale = 0.5;

// Sub-pixel precision of line and marker coordinates: 4 fractional bits.
constexpr int kShift = 4;
constexpr double kShiftScale = 1 << kShift;

const cv::Scalar kAxisGrey(60, 60, 60);
const cv::Scalar kLegendBorderGrey(180, 180, 180);

/// Distinct colours (the "tab10" palette of matplotlib), RGB.
constexpr std::array<Rgb, 10> kPalette = {{
    {31, 119, 180},   // blue
    {255, 127, 14},   // orange
    {44, 160, 44},    // green
    {214, 39, 40},    // red
    {148, 103, 189},  // purple
    {140, 86, 75},    // brown
    {227, 119, 194},  // pink
    {127, 127, 127},  // grey
    {188, 189, 34},   // olive
    {23, 190, 207},   // cyan
}};

cv::Scalar bgr(const Rgb& colour) { return cv::Scalar(colour.blue, colour.green, colour.red); }

std::string format_number(double value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%g", value);
  return text;
}

/// "series[2]" or "series[2] (\"N=5\")", for messages.
std::string series_name(std::size_t index, const LineSeries& series) {
  std::string name = "series[" + std::to_string(index) + "]";
  if (!series.label.empty()) name += " (\"" + series.label + "\")";
  return name;
}

/// A closed interval of data values.
struct Range {
  double min = std::numeric_limits<double>::infinity();
  double max = -std::numeric_limits<double>::infinity();
  void add(double value) {
    min = std::min(min, value);
    max = std::max(max, value);
  }
};

/// Padding for a range of a single value: 5% of the value, or 1 around zero.
double degenerate_pad(double value) { return value == 0.0 ? 1.0 : kDataMargin * std::abs(value); }

/// The data range widened by the margin on both sides.
Range with_margin(Range data, const char* axis) {
  const double span = data.max - data.min;
  if (!std::isfinite(span)) {
    throw std::invalid_argument(std::string(axis) + ": the values span more than a double holds");
  }
  const double pad = span > 0.0 ? kDataMargin * span : degenerate_pad(data.min);
  return {data.min - pad, data.max + pad};
}

/// The y axis: fixed ends where given, the other ends from the data with a margin of the shown
/// span.
Range y_axis_range(const LinePlot& plot, const Range& data) {
  if (plot.y_min && plot.y_max) return {*plot.y_min, *plot.y_max};
  if (plot.y_min) {
    return {*plot.y_min, data.max + kDataMargin * std::max(data.max - *plot.y_min, 0.0)};
  }
  if (plot.y_max) {
    return {data.min - kDataMargin * std::max(*plot.y_max - data.min, 0.0), *plot.y_max};
  }
  return with_margin(data, "y");
}

/// The axis ranges of a valid plot's data; throws std::invalid_argument when they are empty.
std::pair<Range, Range> axis_ranges(const LinePlot& plot) {
  Range x_data;
  Range y_data;
  for (const LineSeries& series : plot.series) {
    for (const double x : series.x) x_data.add(x);
    for (const double y : series.y) y_data.add(y);
  }
  const Range x_axis = with_margin(x_data, "x");
  const Range y_axis = y_axis_range(plot, y_data);
  if (!(y_axis.min < y_axis.max) || !std::isfinite(y_axis.max - y_axis.min)) {
    throw std::invalid_argument("y_min, y_max: the y axis would run from " +
                                format_number(y_axis.min) + " to " + format_number(y_axis.max) +
                                "; the bottom must be below the top");
  }
  return {x_axis, y_axis};
}

/// A tick on an axis, with its label.
struct Tick {
  double value = 0.0;
  std::string label;
};

/// A tick label with as many decimals as the step needs.
std::string tick_label(double value, double step) {
  const int decimals = std::max(0, -static_cast<int>(std::floor(std::log10(step) + 1e-6)));
  char text[64];
  std::snprintf(text, sizeof(text), "%.*f", decimals, value);
  return text;
}

/// Ticks at the multiples of `step` within the range.
std::vector<Tick> step_ticks(double min, double max, double step) {
  std::vector<Tick> ticks;
  const double first = std::ceil(min / step - 1e-9);
  const double last = std::floor(max / step + 1e-9);
  // Bounded by nice_tick_step; the cap only guards against rounding at extreme magnitudes.
  constexpr double kMaxTicks = 1000.0;
  if (!(last - first < kMaxTicks)) return ticks;
  for (int offset = 0; offset <= static_cast<int>(last - first); ++offset) {
    double value = (first + offset) * step;
    if (std::abs(value) < 1e-9 * step) value = 0.0;  // no "-0"
    ticks.push_back({value, tick_label(value, step)});
  }
  return ticks;
}

/// Ticks at the given values within the range.
std::vector<Tick> fixed_ticks(double min, double max, const std::vector<double>& values) {
  std::vector<Tick> ticks;
  for (const double value : values) {
    if (value >= min && value <= max) ticks.push_back({value, format_number(value)});
  }
  return ticks;
}

cv::Size text_size(const std::string& text, double scale, int thickness, int* baseline) {
  int ignored = 0;
  return cv::getTextSize(text, kFont, scale, thickness, baseline != nullptr ? baseline : &ignored);
}

/// Ticks at a round step along an axis of `pixels`: one per `pixels_per_tick` pixels but at least
/// five intervals (so that at least two ticks fall in the range), and fewer where neighbouring
/// labels would come closer than kTickLabelSpacing.
std::vector<Tick> round_ticks(double min, double max, int pixels, int pixels_per_tick,
                              bool horizontal) {
  const double span = max - min;
  for (int intervals = std::max(kMinimumTickIntervals, pixels / pixels_per_tick);; --intervals) {
    const double step = nice_tick_step(span, intervals);
    std::vector<Tick> ticks = step_ticks(min, max, step);
    int longest_label = 0;
    for (const Tick& tick : ticks) {
      const cv::Size size = text_size(tick.label, kTickLabelScale, 1, nullptr);
      longest_label = std::max(longest_label, horizontal ? size.width : size.height);
    }
    if (intervals == 1 || step / span * pixels >= longest_label + kTickLabelSpacing) return ticks;
  }
}

/// Everything that decides where things go, computed once for line_plot_axes and the drawing.
struct Layout {
  LinePlotAxes axes;
  std::vector<Tick> x_ticks;
  std::vector<Tick> y_ticks;
  std::vector<std::size_t> legend_entries;  // indices of the labelled series listed
  std::string legend_more;                  // "... 3 more" when not all fit, else empty
  int legend_width = 0;                     // 0: no legend
};

Layout compute_layout(const LinePlot& plot) {
  validate(plot);
  Layout layout;
  const auto [x_range, y_range] = axis_ranges(plot);
  LinePlotAxes& axes = layout.axes;
  axes.x_min = x_range.min;
  axes.x_max = x_range.max;
  axes.y_min = y_range.min;
  axes.y_max = y_range.max;

  // 1. Vertical: title above, x tick labels and x label below.
  const int tick_label_height = text_size("0123456789", kTickLabelScale, 1, nullptr).height;
  int top = kOuterMargin + 8;
  if (!plot.title.empty()) {
    top = kOuterMargin + text_size(plot.title, kTitleScale, kTitleThickness, nullptr).height + 16;
  }
  int bottom = plot.height - kOuterMargin - tick_label_height - kTickLength - kTickLabelGap - 6;
  if (!plot.x_label.empty()) {
    int baseline = 0;
    bottom -= text_size(plot.x_label, kAxisLabelScale, 1, &baseline).height + baseline + kLabelGap;
  }
  axes.top = top;
  axes.height = std::max(bottom - top, kMinimumPlotSide);
  layout.y_ticks =
      round_ticks(axes.y_min, axes.y_max, axes.height, kMinimumRowsPerYTick, /*horizontal=*/false);

  // 2. Horizontal: y label and y tick labels on the left, the legend on the right.
  int widest_tick_label = 0;
  for (const Tick& tick : layout.y_ticks) {
    widest_tick_label =
        std::max(widest_tick_label, text_size(tick.label, kTickLabelScale, 1, nullptr).width);
  }
  int left = kOuterMargin + widest_tick_label + kTickLabelGap + kTickLength + 2;
  if (!plot.y_label.empty()) {
    int baseline = 0;
    left += text_size(plot.y_label, kAxisLabelScale, 1, &baseline).height + baseline + kLabelGap;
  }
  // As many labelled series as rows fit beside the plot area; a last row counts the others.
  for (std::size_t index = 0; index < plot.series.size(); ++index) {
    if (!plot.series[index].label.empty()) layout.legend_entries.push_back(index);
  }
  const std::size_t legend_rows =
      static_cast<std::size_t>(std::max(1, (axes.height - 2 * kLegendPadding) / kLegendRowHeight));
  if (layout.legend_entries.size() > legend_rows) {
    const std::size_t listed = legend_rows - 1;
    layout.legend_more = "... " + std::to_string(layout.legend_entries.size() - listed) + " more";
    layout.legend_entries.resize(listed);
    layout.legend_width =
        2 * kLegendPadding + text_size(layout.legend_more, kLegendScale, 1, nullptr).width;
  }
  for (const std::size_t index : layout.legend_entries) {
    const int text_width = text_size(plot.series[index].label, kLegendScale, 1, nullptr).width;
    layout.legend_width =
        std::max(layout.legend_width, 3 * kLegendPadding + kLegendSwatchLength + text_width);
  }
  layout.legend_width =
      std::min(layout.legend_width,
               static_cast<int>(kLegendMaxWidthShare * static_cast<double>(plot.width)));
  // Without a legend, room for half of the last x tick label.
  const int right = plot.width - kOuterMargin -
                    (layout.legend_width > 0 ? layout.legend_width + kOuterMargin : 20);
  axes.left = left;
  axes.width = std::max(right - left, kMinimumPlotSide);
  layout.x_ticks = plot.x_ticks.empty()
                       ? round_ticks(axes.x_min, axes.x_max, axes.width, kMinimumColumnsPerXTick,
                                     /*horizontal=*/true)
                       : fixed_ticks(axes.x_min, axes.x_max, plot.x_ticks);
  return layout;
}

/// Sub-pixel point (kShift fractional bits) relative to the plot area, clamped far outside the
/// image so that integer conversion cannot overflow; drawing clips.
cv::Point plot_point(const LinePlotAxes& axes, double x, double y) {
  constexpr double kLimit = 1.0e5;
  const double column = std::clamp(axes.column(x) - axes.left, -kLimit, kLimit);
  const double row = std::clamp(axes.row(y) - axes.top, -kLimit, kLimit);
  return {static_cast<int>(std::lround(column * kShiftScale)),
          static_cast<int>(std::lround(row * kShiftScale))};
}

void draw_segment(cv::Mat& canvas, const cv::Point2d& from, const cv::Point2d& to,
                  const cv::Scalar& colour) {
  cv::line(canvas,
           cv::Point(static_cast<int>(std::lround(from.x)), static_cast<int>(std::lround(from.y))),
           cv::Point(static_cast<int>(std::lround(to.x)), static_cast<int>(std::lround(to.y))),
           colour, kLineThickness, cv::LINE_AA, kShift);
}

/// A polyline of sub-pixel points, solid or dashed; the dash pattern runs on across vertices.
void draw_line(cv::Mat& canvas, const std::vector<cv::Point>& points, const cv::Scalar& colour,
               bool dashed) {
  if (points.size() < 2) return;
  if (!dashed) {
    cv::polylines(canvas, points, false, colour, kLineThickness, cv::LINE_AA, kShift);
    return;
  }
  const double dash = kDashLength * kShiftScale;
  const double period = (kDashLength + kDashGap) * kShiftScale;
  double phase = 0.0;  // distance into the current dash + gap period
  for (std::size_t i = 1; i < points.size(); ++i) {
    const cv::Point2d from = points[i - 1];
    const cv::Point2d to = points[i];
    const double length = cv::norm(to - from);
    double travelled = 0.0;
    while (travelled < length) {
      const bool in_dash = phase < dash;
      const double step = std::min(length - travelled, in_dash ? dash - phase : period - phase);
      if (in_dash) {
        draw_segment(canvas, from + (to - from) * (travelled / length),
                     from + (to - from) * ((travelled + step) / length), colour);
      }
      travelled += step;
      phase = std::fmod(phase + step, period);
    }
  }
}

void draw_marker(cv::Mat& canvas, const cv::Point& point, const cv::Scalar& colour) {
  cv::circle(canvas, point, kMarkerRadius << kShift, colour, cv::FILLED, cv::LINE_AA, kShift);
}

void put_text(cv::Mat& image, const std::string& text, const cv::Point& origin, double scale,
              const cv::Scalar& colour, int thickness = 1) {
  cv::putText(image, text, origin, kFont, scale, colour, thickness, cv::LINE_AA);
}

/// Grid lines, the axis box, ticks and tick labels.
void draw_axes(cv::Mat& image, const Layout& layout) {
  const LinePlotAxes& axes = layout.axes;
  const int right = axes.left + axes.width - 1;
  const int bottom = axes.top + axes.height - 1;
  for (const Tick& tick : layout.x_ticks) {
    const int column = static_cast<int>(std::lround(axes.column(tick.value)));
    cv::line(image, {column, axes.top}, {column, bottom}, kGridGrey, 1);
    cv::line(image, {column, bottom + 1}, {column, bottom + 1 + kTickLength}, kAxisGrey, 1);
    const cv::Size size = text_size(tick.label, kTickLabelScale, 1, nullptr);
    put_text(image, tick.label,
             {column - size.width / 2, bottom + 1 + kTickLength + kTickLabelGap + size.height},
             kTickLabelScale, kAxisGrey);
  }
  for (const Tick& tick : layout.y_ticks) {
    const int row = static_cast<int>(std::lround(axes.row(tick.value)));
    cv::line(image, {axes.left, row}, {right, row}, kGridGrey, 1);
    cv::line(image, {axes.left - 1 - kTickLength, row}, {axes.left - 1, row}, kAxisGrey, 1);
    const cv::Size size = text_size(tick.label, kTickLabelScale, 1, nullptr);
    put_text(image, tick.label,
             {axes.left - 1 - kTickLength - kTickLabelGap - size.width, row + size.height / 2},
             kTickLabelScale, kAxisGrey);
  }
  // The box just outside the plot area, so that the series (clipped to the area) never cover it.
  cv::rectangle(image, {axes.left - 1, axes.top - 1}, {right + 1, bottom + 1}, kAxisGrey, 1);
}

/// The title centred over the plot area, the x label below it, the y label turned on the left.
void draw_labels(cv::Mat& image, const LinePlot& plot, const LinePlotAxes& axes) {
  const int centre_column = axes.left + axes.width / 2;
  if (!plot.title.empty()) {
    const cv::Size size = text_size(plot.title, kTitleScale, kTitleThickness, nullptr);
    const int left = std::max(kOuterMargin, centre_column - size.width / 2);
    put_text(image, plot.title, {left, kOuterMargin + size.height}, kTitleScale, kBlack,
             kTitleThickness);
  }
  if (!plot.x_label.empty()) {
    int baseline = 0;
    const cv::Size size = text_size(plot.x_label, kAxisLabelScale, 1, &baseline);
    const int left = std::max(kOuterMargin, centre_column - size.width / 2);
    put_text(image, plot.x_label, {left, plot.height - kOuterMargin - baseline}, kAxisLabelScale,
             kBlack);
  }
  if (!plot.y_label.empty()) {
    // Drawn level on a small canvas, turned a quarter left, then laid onto the image (darker wins).
    int baseline = 0;
    const cv::Size size = text_size(plot.y_label, kAxisLabelScale, 1, &baseline);
    cv::Mat level(size.height + baseline + 2, size.width + 2, CV_8UC3, kWhite);
    put_text(level, plot.y_label, {1, size.height + 1}, kAxisLabelScale, kBlack);
    cv::Mat turned;
    cv::rotate(level, turned, cv::ROTATE_90_COUNTERCLOCKWISE);
    const int rows = std::min(turned.rows, image.rows);
    const int top = std::clamp(axes.top + axes.height / 2 - rows / 2, 0, image.rows - rows);
    const cv::Rect target(kOuterMargin, top, turned.cols, rows);
    cv::Mat region = image(target);
    cv::min(region, turned(cv::Rect(0, (turned.rows - rows) / 2, turned.cols, rows)), region);
  }
}

/// A box right of the plot area: per labelled series a swatch in its style, then the label.
void draw_legend(cv::Mat& image, const LinePlot& plot, const Layout& layout) {
  if (layout.legend_width == 0) return;
  const LinePlotAxes& axes = layout.axes;
  const int box_left = axes.left + axes.width + kOuterMargin;
  const int rows =
      static_cast<int>(layout.legend_entries.size()) + (layout.legend_more.empty() ? 0 : 1);
  const cv::Rect box(box_left, axes.top, layout.legend_width,
                     rows * kLegendRowHeight + 2 * kLegendPadding - 4);
  cv::rectangle(image, box, kLegendBorderGrey, 1);

  const int swatch_left = box_left + kLegendPadding;
  const int text_left = swatch_left + kLegendSwatchLength + kLegendPadding;
  int row_centre = axes.top + kLegendPadding + kLegendRowHeight / 2 - 2;
  const int text_height = text_size("Ag", kLegendScale, 1, nullptr).height;
  for (const std::size_t index : layout.legend_entries) {
    const LineSeries& series = plot.series[index];
    const cv::Scalar colour = bgr(line_plot_colour(series.colour_index));
    const cv::Point start(swatch_left << kShift, row_centre << kShift);
    const cv::Point end((swatch_left + kLegendSwatchLength) << kShift, row_centre << kShift);
    draw_line(image, {start, end}, colour, series.dashed);
    if (series.markers) draw_marker(image, (start + end) / 2, colour);
    put_text(image, series.label, {text_left, row_centre + text_height / 2}, kLegendScale, kBlack);
    row_centre += kLegendRowHeight;
  }
  if (!layout.legend_more.empty()) {
    put_text(image, layout.legend_more, {swatch_left, row_centre + text_height / 2}, kLegendScale,
             kBlack);
  }
}

// JSON reading helpers; `path` names the field in messages ("series[2].y[3]").

[[noreturn]] void fail(const std::string& path, const std::string& problem) {
  throw std::invalid_argument(path + ": " + problem);
}

std::string got(const nlohmann::json& value) { return std::string("got ") + value.type_name(); }

void reject_unknown_fields(const nlohmann::json& object, const std::string& path,
                           std::initializer_list<const char*> known) {
  for (const auto& item : object.items()) {
    const std::string& key = item.key();  // not a structured binding: clang 14 cannot capture one
    if (std::find_if(known.begin(), known.end(), [&](const char* name) { return key == name; }) ==
        known.end()) {
      std::string expected;
      for (const char* name : known) expected += (expected.empty() ? "" : ", ") + std::string(name);
      fail(path.empty() ? key : path + "." + key,
           "unknown field (expected one of " + expected + ")");
    }
  }
}

std::string read_string(const nlohmann::json& object, const char* key, const std::string& path) {
  if (!object.contains(key)) return {};
  const nlohmann::json& value = object.at(key);
  if (!value.is_string()) fail(path + key, "expected a string, " + got(value));
  return value.get<std::string>();
}

bool read_bool(const nlohmann::json& object, const char* key, const std::string& path,
               bool fallback) {
  if (!object.contains(key)) return fallback;
  const nlohmann::json& value = object.at(key);
  if (!value.is_boolean()) fail(path + key, "expected true or false, " + got(value));
  return value.get<bool>();
}

/// A non-negative integer that fits an int.
int read_count(const nlohmann::json& object, const char* key, const std::string& path,
               int fallback) {
  if (!object.contains(key)) return fallback;
  const nlohmann::json& value = object.at(key);
  if (!value.is_number_integer()) fail(path + key, "expected an integer, " + got(value));
  if (value.is_number_unsigned()
          ? value.get<std::uint64_t>() > static_cast<std::uint64_t>(std::numeric_limits<int>::max())
          : value.get<std::int64_t>() < 0) {
    fail(path + key, "expected an integer from 0 to " +
                         std::to_string(std::numeric_limits<int>::max()) + ", got " + value.dump());
  }
  return value.get<int>();
}

std::optional<double> read_optional_number(const nlohmann::json& object, const char* key) {
  if (!object.contains(key) || object.at(key).is_null()) return std::nullopt;
  const nlohmann::json& value = object.at(key);
  if (!value.is_number()) fail(key, "expected a number or null, " + got(value));
  return value.get<double>();
}

std::vector<double> read_numbers(const nlohmann::json& object, const char* key,
                                 const std::string& path) {
  if (!object.contains(key)) fail(path + key, "missing");
  const nlohmann::json& array = object.at(key);
  if (!array.is_array()) fail(path + key, "expected an array of numbers, " + got(array));
  std::vector<double> numbers;
  numbers.reserve(array.size());
  for (std::size_t index = 0; index < array.size(); ++index) {
    if (!array[index].is_number()) {
      fail(path + key + "[" + std::to_string(index) + "]",
           "expected a number, " + got(array[index]));
    }
    numbers.push_back(array[index].get<double>());
  }
  return numbers;
}

LineSeries parse_series(const nlohmann::json& object, const std::string& name) {
  if (!object.is_object()) fail(name, "expected an object, " + got(object));
  reject_unknown_fields(object, name, {"label", "x", "y", "dashed", "markers", "colour"});
  const std::string path = name + ".";
  LineSeries series;
  series.label = read_string(object, "label", path);
  series.x = read_numbers(object, "x", path);
  series.y = read_numbers(object, "y", path);
  series.dashed = read_bool(object, "dashed", path, series.dashed);
  series.markers = read_bool(object, "markers", path, series.markers);
  series.colour_index = read_count(object, "colour", path, series.colour_index);
  return series;
}

}  // namespace

Rgb line_plot_colour(int colour_index) {
  assert(colour_index >= 0);
  return kPalette[static_cast<std::size_t>(std::max(colour_index, 0)) % kPalette.size()];
}

double LinePlotAxes::column(double x) const {
  return left + (x - x_min) / (x_max - x_min) * (width - 1);
}

double LinePlotAxes::row(double y) const {
  return top + (y_max - y) / (y_max - y_min) * (height - 1);
}

double nice_tick_step(double span, int max_intervals) {
  assert(span > 0.0 && std::isfinite(span) && max_intervals >= 1);
  const double smallest = span / max_intervals;
  const double power = std::pow(10.0, std::floor(std::log10(smallest)));
  for (const double factor : {1.0, 2.0, 5.0}) {
    // The tolerance keeps exact fits (span 1, 5 intervals: step 0.2) from rounding up.
    if (factor * power >= smallest * (1.0 - 1e-9)) return factor * power;
  }
  return 10.0 * power;
}

void validate(const LinePlot& plot) {
  if (plot.width < kMinimumLinePlotWidth) {
    throw std::invalid_argument("width: " + std::to_string(plot.width) + " is below the minimum " +
                                std::to_string(kMinimumLinePlotWidth));
  }
  if (plot.height < kMinimumLinePlotHeight) {
    throw std::invalid_argument("height: " + std::to_string(plot.height) +
                                " is below the minimum " + std::to_string(kMinimumLinePlotHeight));
  }
  if (plot.series.empty()) throw std::invalid_argument("series: the plot has no series");
  for (std::size_t index = 0; index < plot.series.size(); ++index) {
    const LineSeries& series = plot.series[index];
    const std::string name = series_name(index, series);
    if (series.x.size() != series.y.size()) {
      throw std::invalid_argument(name + ": x has " + std::to_string(series.x.size()) +
                                  " values, y has " + std::to_string(series.y.size()));
    }
    if (series.x.empty()) throw std::invalid_argument(name + ": no points");
    for (const auto* values : {&series.x, &series.y}) {
      const char* axis = values == &series.x ? "x" : "y";
      for (std::size_t point = 0; point < values->size(); ++point) {
        if (!std::isfinite((*values)[point])) {
          throw std::invalid_argument(name + ": " + axis + "[" + std::to_string(point) + "] is " +
                                      format_number((*values)[point]) + ", not a finite number");
        }
      }
    }
    if (series.colour_index < 0) {
      throw std::invalid_argument(name + ": colour index " + std::to_string(series.colour_index) +
                                  " is negative");
    }
  }
  for (const auto& [name, end] : {std::pair{"y_min", plot.y_min}, std::pair{"y_max", plot.y_max}}) {
    if (end && !std::isfinite(*end)) {
      throw std::invalid_argument(std::string(name) + ": " + format_number(*end) +
                                  " is not a finite number");
    }
  }
  for (std::size_t index = 0; index < plot.x_ticks.size(); ++index) {
    if (!std::isfinite(plot.x_ticks[index])) {
      throw std::invalid_argument("x_ticks[" + std::to_string(index) + "]: " +
                                  format_number(plot.x_ticks[index]) + " is not a finite number");
    }
  }
  axis_ranges(plot);  // throws for an empty y range
}

LinePlotAxes line_plot_axes(const LinePlot& plot) { return compute_layout(plot).axes; }

void write_line_plot_png(const std::filesystem::path& file, const LinePlot& plot) {
  // 1. Where everything goes (validates the plot).
  const Layout layout = compute_layout(plot);
  const LinePlotAxes& axes = layout.axes;

  // 2. Background, grid, axes and labels.
  cv::Mat image(plot.height, plot.width, CV_8UC3, kWhite);
  draw_axes(image, layout);
  draw_labels(image, plot, axes);

  // 3. The series in the given order, clipped to the plot area (a sub-image); markers over lines.
  cv::Mat plot_area = image(cv::Rect(axes.left, axes.top, axes.width, axes.height));
  for (const LineSeries& series : plot.series) {
    std::vector<cv::Point> points;
    points.reserve(series.x.size());
    for (std::size_t i = 0; i < series.x.size(); ++i) {
      points.push_back(plot_point(axes, series.x[i], series.y[i]));
    }
    const cv::Scalar colour = bgr(line_plot_colour(series.colour_index));
    draw_line(plot_area, points, colour, series.dashed);
    if (series.markers) {
      for (const cv::Point& point : points) draw_marker(plot_area, point, colour);
    }
  }

  // 4. The legend, then the file, replaced atomically.
  draw_legend(image, plot, layout);
  std::vector<unsigned char> png;
  try {
    if (!cv::imencode(".png", image, png)) {
      throw std::runtime_error("cannot encode line plot " + file.string() + " as PNG");
    }
  } catch (const cv::Exception& error) {
    throw std::runtime_error("cannot encode line plot " + file.string() +
                             " as PNG: " + error.what());
  }
  dataset::write_file_atomically(file, std::string(png.begin(), png.end()));
}

LinePlot parse_line_plot(const nlohmann::json& document) {
  if (!document.is_object()) fail("(top level)", "expected an object, " + got(document));
  reject_unknown_fields(
      document, "",
      {"title", "x_label", "y_label", "series", "width", "height", "y_min", "y_max", "x_ticks"});
  LinePlot plot;
  plot.title = read_string(document, "title", "");
  plot.x_label = read_string(document, "x_label", "");
  plot.y_label = read_string(document, "y_label", "");
  plot.width = read_count(document, "width", "", plot.width);
  plot.height = read_count(document, "height", "", plot.height);
  plot.y_min = read_optional_number(document, "y_min");
  plot.y_max = read_optional_number(document, "y_max");
  if (document.contains("x_ticks")) plot.x_ticks = read_numbers(document, "x_ticks", "");
  if (!document.contains("series")) fail("series", "missing");
  const nlohmann::json& series = document.at("series");
  if (!series.is_array()) fail("series", "expected an array of objects, " + got(series));
  for (std::size_t index = 0; index < series.size(); ++index) {
    plot.series.push_back(parse_series(series[index], "series[" + std::to_string(index) + "]"));
  }
  validate(plot);
  return plot;
}

nlohmann::json to_json(const LinePlot& plot) {
  nlohmann::json series = nlohmann::json::array();
  for (const LineSeries& line : plot.series) {
    series.push_back({{"label", line.label},
                      {"x", line.x},
                      {"y", line.y},
                      {"dashed", line.dashed},
                      {"markers", line.markers},
                      {"colour", line.colour_index}});
  }
  const auto optional_number = [](const std::optional<double>& value) {
    return value ? nlohmann::json(*value) : nlohmann::json(nullptr);
  };
  return {{"title", plot.title},
          {"x_label", plot.x_label},
          {"y_label", plot.y_label},
          {"width", plot.width},
          {"height", plot.height},
          {"y_min", optional_number(plot.y_min)},
          {"y_max", optional_number(plot.y_max)},
          {"x_ticks", plot.x_ticks},
          {"series", series}};
}

LinePlot read_line_plot_json(const std::filesystem::path& file) {
  std::ifstream stream(file, std::ios::binary);
  if (!stream) throw std::runtime_error("cannot read line plot " + file.string());
  std::ostringstream content;
  content << stream.rdbuf();
  if (stream.bad()) throw std::runtime_error("cannot read line plot " + file.string());
  try {
    return parse_line_plot(nlohmann::json::parse(content.str()));
  } catch (const nlohmann::json::parse_error& error) {
    throw std::invalid_argument(file.string() + ": not valid JSON: " + error.what());
  } catch (const std::invalid_argument& error) {
    throw std::invalid_argument(file.string() + ": " + error.what());
  }
}

}  // namespace concord::evaluation
