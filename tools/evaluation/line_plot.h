#pragma once
/// \file
/// Line charts written as PNG: one or more series of (x, y) points drawn as solid or dashed lines,
/// optionally with markers, on numbered axes with a title and a legend. Made for the paper's
/// Fig. 4 (consensus RMSE against the link-loss rate, one line per team size, each team's
/// "separate" RMSE as a dashed horizontal line in the same colour) and charts like it. A chart can
/// also come from a JSON file, so that a script without plotting libraries can have it drawn:
///
///     {"title": "...", "x_label": "...", "y_label": "...",
///      "width": 900, "height": 600, "y_min": 0, "y_max": null, "x_ticks": [0, 0.3, 0.6, 0.9],
///      "series": [{"label": "N=3", "x": [0, 0.3], "y": [1.2, 1.4],
///                  "dashed": false, "markers": true, "colour": 0}]}
///
/// Only "series" and each series' "x" and "y" are required; the others default as in LinePlot
/// and LineSeries ("colour" is LineSeries::colour_index; null y_min / y_max means from the data).

#include <cstdint>
#include <filesystem>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <vector>

namespace concord::evaluation {

/// One line of a chart: points joined in the given order.
struct LineSeries {
  /// Legend text; a series with an empty label is drawn but not listed in the legend.
  std::string label;
  /// Point coordinates, as many x as y, all finite.
  std::vector<double> x;
  std::vector<double> y;
  /// Dashed instead of solid.
  bool dashed = false;
  /// A filled dot at every point.
  bool markers = true;
  /// Index into the palette (see line_plot_colour), at least 0. Series with the same index share
  /// a colour, e.g. a team's solid consensus line and its dashed "separate" line.
  int colour_index = 0;
};

/// A whole chart.
struct LinePlot {
  std::string title;
  std::string x_label;
  std::string y_label;
  /// At least one series, each with at least one point.
  std::vector<LineSeries> series;
  /// Image size in pixels, at least kMinimumLinePlotWidth x kMinimumLinePlotHeight.
  int width = 900;
  int height = 600;
  /// Fixed ends of the y axis; an end left empty comes from the data with a 5% margin.
  std::optional<double> y_min;
  std::optional<double> y_max;
  /// Where to put the x ticks (e.g. at the measured link-loss rates); empty: every multiple of a
  /// round step (see nice_tick_step). Ticks outside the x range are left out.
  std::vector<double> x_ticks;
};

/// Smallest image write_line_plot_png accepts, in pixels.
inline constexpr int kMinimumLinePlotWidth = 300;
inline constexpr int kMinimumLinePlotHeight = 200;

/// A palette colour, 8 bits per channel.
struct Rgb {
  std::uint8_t red = 0;
  std::uint8_t green = 0;
  std::uint8_t blue = 0;
  friend bool operator==(const Rgb&, const Rgb&) = default;
};

/// The colour of palette entry `colour_index` (>= 0): 10 distinct colours, then repeating.
Rgb line_plot_colour(int colour_index);

/// Where write_line_plot_png puts the data: the axis ranges and the plot area in image pixels
/// (columns to the right, rows down).
struct LinePlotAxes {
  /// Data range shown: x from the data with a 5% margin, y as described at LinePlot::y_min.
  double x_min = 0.0;
  double x_max = 1.0;
  double y_min = 0.0;
  double y_max = 1.0;
  /// The plot area: columns [left, left + width), rows [top, top + height).
  int left = 0;
  int top = 0;
  int width = 1;
  int height = 1;

  /// Image column of data x (x_min at the left edge, x_max at the right), not rounded.
  double column(double x) const;
  /// Image row of data y (y_max at the top edge, y_min at the bottom), not rounded.
  double row(double y) const;
};

/// Throws std::invalid_argument naming the first problem (e.g. "series[1] (\"N=5\"): x has 4
/// values, y has 3"): no series, a series without points, x and y of different lengths, a
/// non-finite value (also in y_min, y_max, x_ticks), a negative colour index, an image below the
/// minimum size, or y_min >= y_max.
void validate(const LinePlot& plot);

/// The axes write_line_plot_png draws `plot` on. Validates first (see validate).
LinePlotAxes line_plot_axes(const LinePlot& plot);

/// The step between axis ticks: the smallest of 1, 2 or 5 times a power of ten that cuts `span`
/// (> 0) into at most `max_intervals` (>= 1) intervals.
double nice_tick_step(double span, int max_intervals);

/// Draws `plot`: white background, light grid, axes with numbered ticks, axis labels, the title,
/// the series (anti-aliased, clipped to the plot area, in the given order) and a legend to the
/// right of the plot area listing each labelled series with its colour, line style and marker.
/// Replaces `file` atomically (a temporary file in the same folder, then a rename). Throws
/// std::invalid_argument for an invalid plot (see validate) and std::runtime_error naming the file
/// when it cannot be written.
void write_line_plot_png(const std::filesystem::path& file, const LinePlot& plot);

/// A chart from JSON of the form in the file comment. Throws std::invalid_argument naming the bad
/// field (e.g. "series[2].y[3]: expected a number, got null") for a wrong type, a missing or
/// unknown field, or a plot that fails validate.
LinePlot parse_line_plot(const nlohmann::json& document);

/// The JSON form of `plot` (parse_line_plot gives it back). Every field is written; an empty
/// y_min or y_max is written as null.
nlohmann::json to_json(const LinePlot& plot);

/// parse_line_plot of a JSON file. Throws std::runtime_error when the file cannot be read and
/// std::invalid_argument, starting with the file name, when its content is not valid JSON or not a
/// valid chart.
LinePlot read_line_plot_json(const std::filesystem::path& file);

}  // namespace concord::evaluation
