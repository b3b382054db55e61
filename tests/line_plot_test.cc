// The line-plot PNG writer (paper Fig. 4 and similar charts) and its JSON form: the image is read
// back and its pixels checked at the positions the axis mapping gives.

#include "evaluation/line_plot.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <set>
#include <stdexcept>
#include <string>
#include <tuple>
#include <vector>

namespace concord::evaluation {
namespace {

/// A fresh, empty folder under the test temporary directory.
std::filesystem::path scratch_directory(const std::string& name) {
  const std::filesystem::path directory =
      std::filesystem::path(::testing::TempDir()) / ("concord_line_plot_" + name);
  std::filesystem::remove_all(directory);
  std::filesystem::create_directories(directory);
  return directory;
}

/// Writes `plot` and reads it back as BGR.
cv::Mat render(const LinePlot& plot, const std::string& name) {
  const std::filesystem::path directory = scratch_directory(name);
  const std::filesystem::path file = directory / "plot.png";
  write_line_plot_png(file, plot);
  cv::Mat image = cv::imread(file.string(), cv::IMREAD_COLOR);
  std::filesystem::remove_all(directory);
  return image;
}

bool has_colour(const cv::Vec3b& pixel, const Rgb& colour, int tolerance = 40) {
  return std::abs(pixel[2] - colour.red) <= tolerance &&
         std::abs(pixel[1] - colour.green) <= tolerance &&
         std::abs(pixel[0] - colour.blue) <= tolerance;
}

bool is_background(const cv::Vec3b& pixel) {
  return pixel[0] >= 250 && pixel[1] >= 250 && pixel[2] >= 250;
}

/// One unlabelled horizontal series at `y` from x = 0 to 1, on a y axis from 0 to 4.
LinePlot horizontal_line(double y, bool dashed) {
  LinePlot plot;
  plot.title = "horizontal";
  plot.x_label = "x";
  plot.y_label = "y";
  plot.y_min = 0.0;
  plot.y_max = 4.0;
  LineSeries series;
  series.x = {0.0, 0.5, 1.0};
  series.y = {y, y, y};
  series.dashed = dashed;
  series.markers = false;
  series.colour_index = 3;
  plot.series = {series};
  return plot;
}

/// Pixels of the image row at data y, between data x = 0.1 and 0.9.
std::vector<cv::Vec3b> pixels_along(const cv::Mat& image, const LinePlotAxes& axes, double y) {
  const int row = static_cast<int>(std::lround(axes.row(y)));
  std::vector<cv::Vec3b> pixels;
  for (int column = static_cast<int>(std::lround(axes.column(0.1)));
       column <= static_cast<int>(std::lround(axes.column(0.9))); ++column) {
    pixels.push_back(image.at<cv::Vec3b>(row, column));
  }
  return pixels;
}

/// Paper Fig. 4 with made-up numbers, in the JSON form a bench script writes.
nlohmann::json figure_4_json() {
  const std::vector<double> loss_rates = {0.0, 0.3, 0.6, 0.9};
  const std::vector<std::tuple<int, std::vector<double>, double>> teams = {
      {3, {1.10, 1.16, 1.27, 1.58}, 1.92},
      {5, {0.92, 0.97, 1.08, 1.41}, 1.88},
      {10, {0.71, 0.75, 0.84, 1.19}, 1.95},
      {15, {0.63, 0.66, 0.74, 1.06}, 1.90}};
  nlohmann::json series = nlohmann::json::array();
  int colour = 0;
  for (const auto& [robots, consensus, separate] : teams) {
    const std::string team = "N=" + std::to_string(robots);
    series.push_back(
        {{"label", team + " consensus"}, {"x", loss_rates}, {"y", consensus}, {"colour", colour}});
    series.push_back({{"label", team + " separate"},
                      {"x", {0.0, 0.9}},
                      {"y", {separate, separate}},
                      {"dashed", true},
                      {"markers", false},
                      {"colour", colour}});
    ++colour;
  }
  return {{"title", "Trajectory RMSE against link-loss rate"},
          {"x_label", "link-loss rate r"},
          {"y_label", "trajectory RMSE [m]"},
          {"y_min", 0.0},
          {"x_ticks", loss_rates},
          {"series", series}};
}

TEST(LinePlotTest, WritesAPngOfTheRequestedSize) {
  LinePlot plot = horizontal_line(2.0, false);
  plot.width = 640;
  plot.height = 480;
  const cv::Mat image = render(plot, "size");
  ASSERT_FALSE(image.empty());
  EXPECT_EQ(image.cols, 640);
  EXPECT_EQ(image.rows, 480);
  double darkest = 0.0;
  double brightest = 0.0;
  cv::Mat grey;
  cv::extractChannel(image, grey, 1);
  cv::minMaxLoc(grey, &darkest, &brightest);
  EXPECT_LT(darkest, 100.0);  // text and axes
  EXPECT_EQ(brightest, 255.0);
}

TEST(LinePlotTest, AxesMapTheDataRangeOntoThePlotArea) {
  const LinePlot plot = horizontal_line(2.0, false);
  const LinePlotAxes axes = line_plot_axes(plot);
  // x from the data with a 5% margin; y as fixed.
  EXPECT_DOUBLE_EQ(axes.x_min, -0.05);
  EXPECT_DOUBLE_EQ(axes.x_max, 1.05);
  EXPECT_DOUBLE_EQ(axes.y_min, 0.0);
  EXPECT_DOUBLE_EQ(axes.y_max, 4.0);
  EXPECT_DOUBLE_EQ(axes.column(axes.x_min), axes.left);
  EXPECT_DOUBLE_EQ(axes.column(axes.x_max), axes.left + axes.width - 1);
  EXPECT_DOUBLE_EQ(axes.row(axes.y_max), axes.top);
  EXPECT_DOUBLE_EQ(axes.row(axes.y_min), axes.top + axes.height - 1);
  // The plot area lies inside the image with room for labels around it, and the legend-less
  // plot uses most of the width.
  EXPECT_GT(axes.left, 30);
  EXPECT_GT(axes.top, 20);
  EXPECT_LT(axes.left + axes.width, plot.width);
  EXPECT_LT(axes.top + axes.height, plot.height - 30);
  EXPECT_GT(axes.width, plot.width / 2);
}

TEST(LinePlotTest, YRangeComesFromTheDataWithAMarginUnlessFixed) {
  LinePlot plot;
  plot.series = {{.label = "a", .x = {0.0, 1.0, 2.0}, .y = {1.0, 3.0, 2.0}}};
  LinePlotAxes axes = line_plot_axes(plot);
  EXPECT_DOUBLE_EQ(axes.x_min, -0.1);
  EXPECT_DOUBLE_EQ(axes.x_max, 2.1);
  EXPECT_DOUBLE_EQ(axes.y_min, 0.9);
  EXPECT_DOUBLE_EQ(axes.y_max, 3.1);

  plot.y_min = 0.0;  // the margin is then of the shown span
  axes = line_plot_axes(plot);
  EXPECT_DOUBLE_EQ(axes.y_min, 0.0);
  EXPECT_DOUBLE_EQ(axes.y_max, 3.15);

  // A single value still gives a range.
  LinePlot point;
  point.series = {{.label = "point", .x = {2.0}, .y = {0.0}}};
  axes = line_plot_axes(point);
  EXPECT_LT(axes.x_min, 2.0);
  EXPECT_GT(axes.x_max, 2.0);
  EXPECT_LT(axes.y_min, 0.0);
  EXPECT_GT(axes.y_max, 0.0);
}

TEST(LinePlotTest, HorizontalSeriesIsDrawnInItsColourAtTheMappedRow) {
  const LinePlot plot = horizontal_line(2.0, false);
  const Rgb colour = line_plot_colour(3);
  const cv::Mat image = render(plot, "solid");
  const LinePlotAxes axes = line_plot_axes(plot);

  const std::vector<cv::Vec3b> on_line = pixels_along(image, axes, 2.0);
  ASSERT_GT(on_line.size(), 300u);
  for (const cv::Vec3b& pixel : on_line) {
    ASSERT_TRUE(has_colour(pixel, colour)) << pixel;
  }
  // Nowhere else: not a quarter of the axis away, nor outside the plot area (no legend, since the
  // series has no label).
  for (const cv::Vec3b& pixel : pixels_along(image, axes, 3.0)) {
    EXPECT_FALSE(has_colour(pixel, colour)) << pixel;
  }
  const cv::Rect plot_area(axes.left, axes.top, axes.width, axes.height);
  int coloured_outside = 0;
  for (int row = 0; row < image.rows; ++row) {
    for (int column = 0; column < image.cols; ++column) {
      if (!plot_area.contains({column, row}) &&
          has_colour(image.at<cv::Vec3b>(row, column), colour, 10)) {
        ++coloured_outside;
      }
    }
  }
  EXPECT_EQ(coloured_outside, 0);
}

TEST(LinePlotTest, DashedLineLeavesGapsAndSolidLineDoesNot) {
  // y = 1.3 is on no grid line, so the gaps show the white background.
  const Rgb colour = line_plot_colour(3);
  for (const bool dashed : {true, false}) {
    SCOPED_TRACE(dashed ? "dashed" : "solid");
    const LinePlot plot = horizontal_line(1.3, dashed);
    const cv::Mat image = render(plot, dashed ? "dashed" : "undashed");
    const std::vector<cv::Vec3b> pixels = pixels_along(image, line_plot_axes(plot), 1.3);
    ASSERT_GT(pixels.size(), 300u);
    int coloured = 0;
    int background = 0;
    int gaps = 0;  // runs of background pixels
    for (std::size_t index = 0; index < pixels.size(); ++index) {
      coloured += has_colour(pixels[index], colour) ? 1 : 0;
      if (is_background(pixels[index])) {
        ++background;
        if (index == 0 || !is_background(pixels[index - 1])) ++gaps;
      }
    }
    const double total = static_cast<double>(pixels.size());
    if (dashed) {
      // Dashes of 10 pixels, gaps of 7 narrowed by the round, anti-aliased dash ends.
      EXPECT_GT(coloured, 0.4 * total);
      EXPECT_GT(background, 0.08 * total);
      EXPECT_GT(gaps, static_cast<int>(total / 17.0) - 2);
    } else {
      EXPECT_EQ(coloured, static_cast<int>(pixels.size()));
      EXPECT_EQ(background, 0);
    }
  }
}

TEST(LinePlotTest, MarkersAreDrawnOnlyWhenAsked) {
  for (const bool markers : {true, false}) {
    SCOPED_TRACE(markers ? "markers" : "no markers");
    LinePlot plot = horizontal_line(2.0, false);
    plot.series[0].markers = markers;
    const cv::Mat image = render(plot, markers ? "markers" : "no_markers");
    const LinePlotAxes axes = line_plot_axes(plot);
    // Three pixels above the middle point: inside a marker, off the 2-pixel line.
    const cv::Vec3b pixel = image.at<cv::Vec3b>(static_cast<int>(std::lround(axes.row(2.0))) - 3,
                                                static_cast<int>(std::lround(axes.column(0.5))));
    EXPECT_EQ(has_colour(pixel, line_plot_colour(3)), markers) << pixel;
  }
}

TEST(LinePlotTest, LabelledSeriesAppearInTheLegendInTheirColour) {
  LinePlot plot = horizontal_line(2.0, false);
  plot.series[0].label = "team";
  const Rgb colour = line_plot_colour(3);
  const cv::Mat image = render(plot, "legend");
  const LinePlotAxes axes = line_plot_axes(plot);
  EXPECT_LT(axes.width, plot.width - 100);  // room for the legend
  int coloured_right_of_plot = 0;
  for (int row = 0; row < image.rows; ++row) {
    for (int column = axes.left + axes.width + 1; column < image.cols; ++column) {
      if (has_colour(image.at<cv::Vec3b>(row, column), colour, 10)) ++coloured_right_of_plot;
    }
  }
  EXPECT_GT(coloured_right_of_plot, 40);  // the swatch line and marker
}

TEST(LinePlotTest, PaletteHasDistinctColoursAndRepeats) {
  std::set<std::tuple<int, int, int>> distinct;
  for (int index = 0; index < 10; ++index) {
    const Rgb colour = line_plot_colour(index);
    distinct.insert({colour.red, colour.green, colour.blue});
  }
  EXPECT_EQ(distinct.size(), 10u);
  EXPECT_EQ(line_plot_colour(10), line_plot_colour(0));
  EXPECT_EQ(line_plot_colour(13), line_plot_colour(3));
}

TEST(LinePlotTest, TickStepsAreOneTwoOrFiveTimesAPowerOfTen) {
  EXPECT_DOUBLE_EQ(nice_tick_step(1.0, 5), 0.2);
  EXPECT_DOUBLE_EQ(nice_tick_step(10.0, 5), 2.0);
  EXPECT_DOUBLE_EQ(nice_tick_step(0.9, 6), 0.2);
  EXPECT_DOUBLE_EQ(nice_tick_step(7.0, 10), 1.0);
  EXPECT_DOUBLE_EQ(nice_tick_step(3.3, 4), 1.0);
  EXPECT_DOUBLE_EQ(nice_tick_step(1234.0, 5), 500.0);
  EXPECT_DOUBLE_EQ(nice_tick_step(0.0012, 3), 0.0005);
  EXPECT_DOUBLE_EQ(nice_tick_step(95.0, 1), 100.0);
}

/// Expects write_line_plot_png (and validate) to throw std::invalid_argument whose message
/// contains `expected`, without creating the file.
void expect_invalid(const LinePlot& plot, const std::string& expected) {
  EXPECT_THROW(validate(plot), std::invalid_argument);
  const std::filesystem::path directory = scratch_directory("invalid");
  const std::filesystem::path file = directory / "plot.png";
  try {
    write_line_plot_png(file, plot);
    ADD_FAILURE() << "expected std::invalid_argument containing " << expected;
  } catch (const std::invalid_argument& error) {
    EXPECT_NE(std::string(error.what()).find(expected), std::string::npos) << error.what();
  }
  EXPECT_FALSE(std::filesystem::exists(file));
  std::filesystem::remove_all(directory);
}

TEST(LinePlotTest, InvalidPlotsThrowNamingTheProblem) {
  const LinePlot valid = horizontal_line(2.0, false);
  EXPECT_NO_THROW(validate(valid));

  LinePlot plot = valid;
  plot.series.clear();
  expect_invalid(plot, "no series");

  plot = valid;
  plot.series[0].label = "N=5";
  plot.series[0].y.pop_back();
  expect_invalid(plot, "series[0] (\"N=5\"): x has 3 values, y has 2");

  plot = valid;
  plot.series[0].x.clear();
  plot.series[0].y.clear();
  expect_invalid(plot, "series[0]: no points");

  plot = valid;
  plot.series[0].y[1] = std::numeric_limits<double>::quiet_NaN();
  expect_invalid(plot, "y[1] is nan");

  plot = valid;
  plot.series.push_back(valid.series[0]);
  plot.series[1].x[2] = std::numeric_limits<double>::infinity();
  expect_invalid(plot, "series[1]: x[2] is inf");

  plot = valid;
  plot.series[0].colour_index = -1;
  expect_invalid(plot, "colour index -1");

  plot = valid;
  plot.width = 50;
  expect_invalid(plot, "width");

  plot = valid;
  plot.y_min = 5.0;
  expect_invalid(plot, "y_min, y_max");

  plot = valid;
  plot.y_max = std::numeric_limits<double>::quiet_NaN();
  expect_invalid(plot, "y_max");

  plot = valid;
  plot.x_ticks = {0.0, -std::numeric_limits<double>::infinity()};
  expect_invalid(plot, "x_ticks[1]: -inf");
}

TEST(LinePlotTest, UnwritableFileThrowsNamingTheFile) {
  const std::filesystem::path file =
      std::filesystem::path(::testing::TempDir()) / "no_such_directory" / "plot.png";
  try {
    write_line_plot_png(file, horizontal_line(2.0, false));
    FAIL() << "expected std::runtime_error";
  } catch (const std::runtime_error& error) {
    EXPECT_NE(std::string(error.what()).find(file.string()), std::string::npos) << error.what();
  }
}

TEST(LinePlotTest, WritingReplacesTheFileAndLeavesNoTemporaryFile) {
  const std::filesystem::path directory = scratch_directory("atomic");
  const std::filesystem::path file = directory / "plot.png";
  {
    std::ofstream old(file);
    old << "not a png";
  }
  write_line_plot_png(file, horizontal_line(2.0, false));
  EXPECT_FALSE(cv::imread(file.string()).empty());
  std::vector<std::filesystem::path> entries;
  for (const auto& entry : std::filesystem::directory_iterator(directory)) {
    entries.push_back(entry.path());
  }
  EXPECT_EQ(entries, std::vector<std::filesystem::path>{file});
  std::filesystem::remove_all(directory);
}

TEST(LinePlotTest, JsonRoundTripKeepsEveryField) {
  LinePlot plot;
  plot.title = "title";
  plot.x_label = "x label";
  plot.y_label = "y label";
  plot.width = 800;
  plot.height = 500;
  plot.y_min = 0.0;
  plot.x_ticks = {0.0, 0.3};
  plot.series = {{.label = "solid", .x = {0.0, 0.3}, .y = {1.25, 1.5}, .colour_index = 2},
                 {.label = "dashed",
                  .x = {0.0, 0.9},
                  .y = {2.0, 2.0},
                  .dashed = true,
                  .markers = false,
                  .colour_index = 12}};

  const nlohmann::json document = to_json(plot);
  EXPECT_EQ(document.at("series").at(1).at("colour"), 12);
  EXPECT_TRUE(document.at("y_max").is_null());
  const LinePlot parsed = parse_line_plot(nlohmann::json::parse(document.dump()));
  EXPECT_EQ(parsed.title, plot.title);
  EXPECT_EQ(parsed.x_label, plot.x_label);
  EXPECT_EQ(parsed.y_label, plot.y_label);
  EXPECT_EQ(parsed.width, plot.width);
  EXPECT_EQ(parsed.height, plot.height);
  EXPECT_EQ(parsed.y_min, plot.y_min);
  EXPECT_EQ(parsed.y_max, std::nullopt);
  EXPECT_EQ(parsed.x_ticks, plot.x_ticks);
  ASSERT_EQ(parsed.series.size(), 2u);
  for (std::size_t index = 0; index < 2; ++index) {
    const LineSeries& expected = plot.series[index];
    const LineSeries& actual = parsed.series[index];
    EXPECT_EQ(actual.label, expected.label);
    EXPECT_EQ(actual.x, expected.x);
    EXPECT_EQ(actual.y, expected.y);
    EXPECT_EQ(actual.dashed, expected.dashed);
    EXPECT_EQ(actual.markers, expected.markers);
    EXPECT_EQ(actual.colour_index, expected.colour_index);
  }
  EXPECT_EQ(to_json(parsed), document);
}

TEST(LinePlotTest, JsonFieldsOtherThanXAndYAreOptional) {
  const LinePlot plot =
      parse_line_plot(nlohmann::json::parse(R"({"series": [{"x": [1, 2], "y": [3, 4.5]}]})"));
  const LinePlot defaults;
  EXPECT_EQ(plot.title, "");
  EXPECT_EQ(plot.width, defaults.width);
  EXPECT_EQ(plot.height, defaults.height);
  EXPECT_FALSE(plot.y_min.has_value());
  EXPECT_FALSE(plot.y_max.has_value());
  EXPECT_TRUE(plot.x_ticks.empty());
  ASSERT_EQ(plot.series.size(), 1u);
  EXPECT_EQ(plot.series[0].label, "");
  EXPECT_EQ(plot.series[0].x, (std::vector<double>{1.0, 2.0}));
  EXPECT_EQ(plot.series[0].y, (std::vector<double>{3.0, 4.5}));
  EXPECT_FALSE(plot.series[0].dashed);
  EXPECT_TRUE(plot.series[0].markers);
  EXPECT_EQ(plot.series[0].colour_index, 0);
}

TEST(LinePlotTest, JsonErrorsNameTheField) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {R"([])", "(top level): expected an object"},
      {R"({})", "series: missing"},
      {R"({"series": {"x": [0]}})", "series: expected an array"},
      {R"({"series": []})", "series: the plot has no series"},
      {R"({"series": [3]})", "series[0]: expected an object, got number"},
      {R"({"series": [{"y": [1]}]})", "series[0].x: missing"},
      {R"({"series": [{"x": 0, "y": [1]}]})", "series[0].x: expected an array of numbers"},
      {R"({"series": [{"x": [0, 1], "y": [1, null]}]})",
       "series[0].y[1]: expected a number, got null"},
      {R"({"series": [{"x": [0, 1], "y": [1]}]})", "series[0]: x has 2 values, y has 1"},
      {R"({"series": [{"x": [0], "y": [1]}, {"x": [0], "y": [1], "dashed": "yes"}]})",
       "series[1].dashed: expected true or false, got string"},
      {R"({"series": [{"x": [0], "y": [1], "markers": 1}]})", "series[0].markers"},
      {R"({"series": [{"x": [0], "y": [1], "colour": -1}]})", "series[0].colour"},
      {R"({"series": [{"x": [0], "y": [1], "colour": 1.5}]})",
       "series[0].colour: expected an integer"},
      {R"({"series": [{"x": [0], "y": [1], "color": 1}]})", "series[0].color: unknown field"},
      {R"({"series": [{"x": [0], "y": [1], "label": 5}]})", "series[0].label: expected a string"},
      {R"({"title": 3, "series": [{"x": [0], "y": [1]}]})", "title: expected a string"},
      {R"({"x_label": null, "series": [{"x": [0], "y": [1]}]})", "x_label: expected a string"},
      {R"({"width": "wide", "series": [{"x": [0], "y": [1]}]})", "width: expected an integer"},
      {R"({"height": 10, "series": [{"x": [0], "y": [1]}]})", "height: 10 is below the minimum"},
      {R"({"y_min": "0", "series": [{"x": [0], "y": [1]}]})", "y_min: expected a number or null"},
      {R"({"y_min": 2, "y_max": 1, "series": [{"x": [0], "y": [1]}]})", "y_min, y_max"},
      {R"({"x_ticks": [0, "a"], "series": [{"x": [0], "y": [1]}]})",
       "x_ticks[1]: expected a number"},
      {R"({"legend": true, "series": [{"x": [0], "y": [1]}]})", "legend: unknown field"},
  };
  for (const auto& [text, expected] : cases) {
    SCOPED_TRACE(text);
    try {
      parse_line_plot(nlohmann::json::parse(text));
      ADD_FAILURE() << "expected std::invalid_argument containing " << expected;
    } catch (const std::invalid_argument& error) {
      EXPECT_EQ(std::string(error.what()).rfind(expected, 0), 0u) << error.what();
    }
  }
}

TEST(LinePlotTest, JsonFileIsReadOrRejectedNamingTheFile) {
  const std::filesystem::path directory = scratch_directory("json_file");
  const std::filesystem::path good = directory / "good.json";
  const std::filesystem::path bad = directory / "bad.json";
  const std::filesystem::path invalid = directory / "invalid.json";
  std::ofstream(good) << figure_4_json().dump(2);
  std::ofstream(bad) << R"({"series": [)";
  std::ofstream(invalid) << R"({"series": []})";

  EXPECT_EQ(read_line_plot_json(good).series.size(), 8u);
  for (const auto& [file, expected] :
       {std::pair{bad, std::string("not valid JSON")}, std::pair{invalid, std::string("series")}}) {
    try {
      read_line_plot_json(file);
      ADD_FAILURE() << "expected std::invalid_argument for " << file;
    } catch (const std::invalid_argument& error) {
      const std::string message = error.what();
      EXPECT_EQ(message.rfind(file.string() + ": ", 0), 0u) << message;
      EXPECT_NE(message.find(expected), std::string::npos) << message;
    }
  }
  EXPECT_THROW(read_line_plot_json(directory / "missing.json"), std::runtime_error);
  std::filesystem::remove_all(directory);
}

TEST(LinePlotTest, Figure4FromJsonShowsEveryTeamColourInThePlotArea) {
  const LinePlot plot = parse_line_plot(figure_4_json());
  // CONCORD_LINE_PLOT_EXAMPLE names a file to keep the figure in, for a look at it.
  if (const char* example = std::getenv("CONCORD_LINE_PLOT_EXAMPLE")) {
    write_line_plot_png(example, plot);
  }
  const cv::Mat image = render(plot, "figure_4");
  ASSERT_EQ(image.cols, plot.width);
  ASSERT_EQ(image.rows, plot.height);
  const LinePlotAxes axes = line_plot_axes(plot);
  EXPECT_DOUBLE_EQ(axes.y_min, 0.0);
  for (int team = 0; team < 4; ++team) {
    SCOPED_TRACE(team);
    // The separate RMSE (dashed) and the consensus RMSE at r = 0.3 (a marker) in the team colour.
    const double separate = figure_4_json()["series"][2 * team + 1]["y"][0].get<double>();
    const double consensus = figure_4_json()["series"][2 * team]["y"][1].get<double>();
    int on_dashed_line = 0;
    for (const cv::Vec3b& pixel : pixels_along(image, axes, separate)) {
      on_dashed_line += has_colour(pixel, line_plot_colour(team)) ? 1 : 0;
    }
    EXPECT_GT(on_dashed_line, 50);
    const cv::Vec3b marker = image.at<cv::Vec3b>(static_cast<int>(std::lround(axes.row(consensus))),
                                                 static_cast<int>(std::lround(axes.column(0.3))));
    EXPECT_TRUE(has_colour(marker, line_plot_colour(team))) << marker;
  }
}

}  // namespace
}  // namespace concord::evaluation
