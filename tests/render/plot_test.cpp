// Tests of the plot renderer: layout and the data → pixel transform (linear and log), markers,
// lines and colours at their pixels, text, tick placement and labels, errors and PNG files.
#include "flsh/render/plot.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <set>
#include <string>
#include <vector>

#include "flsh/core/error.h"
#include "support/test_support.h"

namespace flsh::render {
namespace {

const double kNaN = std::numeric_limits<double>::quiet_NaN();
const double kInf = std::numeric_limits<double>::infinity();

// The 8-bit colour a series colour is drawn with.
std::array<int, 3> bytesOf(const Vec3& color) {
  return {int(std::lround(color[0] * 255)), int(std::lround(color[1] * 255)),
          int(std::lround(color[2] * 255))};
}

bool pixelIs(const Image& image, int x, int y, const std::array<int, 3>& rgb) {
  const uint8_t* p = image.pixel(x, y);
  return p[0] == rgb[0] && p[1] == rgb[1] && p[2] == rgb[2];
}

bool pixelIs(const Image& image, int x, int y, const Vec3& color) {
  return pixelIs(image, x, y, bytesOf(color));
}

long countPixels(const Image& image, const Vec3& color) {
  long count = 0;
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) count += pixelIs(image, x, y, color);
  return count;
}

const std::array<int, 3> kWhiteBytes = {255, 255, 255}, kBlackBytes = {0, 0, 0};
const std::array<int, 3> kGridBytes = {225, 225, 225};  // the renderer's grid colour

PlotSeries makeSeries(const std::string& label, std::vector<double> x, std::vector<double> y,
                      const Vec3& color) {
  PlotSeries series;
  series.label = label;
  series.x = std::move(x);
  series.y = std::move(y);
  series.color = color;
  return series;
}

PlotOptions squareRange(double lo, double hi) {
  PlotOptions options;
  options.x_min = options.y_min = lo;
  options.x_max = options.y_max = hi;
  return options;
}

// Bounding box (x0, y0, x1, y1) of the pixels where two same-sized images differ; x0 = −1 if
// they are equal.
std::array<int, 4> differenceBox(const Image& a, const Image& b) {
  std::array<int, 4> box = {-1, -1, -1, -1};
  for (int y = 0; y < a.height; ++y) {
    for (int x = 0; x < a.width; ++x) {
      const uint8_t* p = a.pixel(x, y);
      const uint8_t* q = b.pixel(x, y);
      if (p[0] == q[0] && p[1] == q[1] && p[2] == q[2]) continue;
      if (box[0] < 0) box = {x, y, x, y};
      box = {std::min(box[0], x), std::min(box[1], y), std::max(box[2], x), std::max(box[3], y)};
    }
  }
  return box;
}

TEST(Plot, ImageHasTheRequestedSizeAndAWhiteBackground) {
  PlotOptions options;
  options.width = 640;
  options.height = 360;
  const Image image =
      renderPlot({makeSeries("data", {1, 2, 3}, {3, 1, 2}, Vec3(0.8, 0.1, 0.1))}, options);
  ASSERT_EQ(image.width, 640);
  ASSERT_EQ(image.height, 360);
  ASSERT_EQ(image.rgb.size(), size_t(640) * 360 * 3);
  // The bottom-right and top-right corners are far from ticks, labels and the (absent) title.
  for (int dy = 0; dy < 4; ++dy) {
    for (int dx = 0; dx < 4; ++dx) {
      EXPECT_TRUE(pixelIs(image, 639 - dx, 359 - dy, kWhiteBytes));
      EXPECT_TRUE(pixelIs(image, 639 - dx, dy, kWhiteBytes));
    }
  }
  // And the axes box is there: the plot-area corner is black.
  const PlotFrame frame =
      plotFrame({makeSeries("data", {1, 2, 3}, {3, 1, 2}, Vec3(0.8, 0.1, 0.1))}, options);
  EXPECT_TRUE(pixelIs(image, frame.left, frame.bottom, kBlackBytes));
}

TEST(Plot, FrameMapsLinearRangesOntoThePlotArea) {
  PlotOptions options;
  options.x_min = 0, options.x_max = 10, options.y_min = -1, options.y_max = 1;
  const PlotFrame frame = plotFrame({}, options);
  EXPECT_EQ(frame.width, 900);
  EXPECT_EQ(frame.height, 600);
  EXPECT_GT(frame.left, 0);
  EXPECT_GT(frame.top, 0);
  EXPECT_GT(frame.right - frame.left, 600);
  EXPECT_GT(frame.bottom - frame.top, 400);
  EXPECT_LT(frame.right, 900);
  EXPECT_LT(frame.bottom, 600);
  EXPECT_EQ(frame.x_min, 0);
  EXPECT_EQ(frame.x_max, 10);
  EXPECT_DOUBLE_EQ(frame.pixelX(0), frame.left);
  EXPECT_DOUBLE_EQ(frame.pixelX(10), frame.right);
  EXPECT_DOUBLE_EQ(frame.pixelX(2.5), frame.left + 0.25 * (frame.right - frame.left));
  EXPECT_DOUBLE_EQ(frame.pixelY(-1), frame.bottom);  // rows grow downwards
  EXPECT_DOUBLE_EQ(frame.pixelY(1), frame.top);
  EXPECT_DOUBLE_EQ(frame.pixelY(0.5), frame.bottom - 0.75 * (frame.bottom - frame.top));
}

TEST(Plot, FrameMapsLogRangesLogLinearly) {
  PlotOptions options;
  options.log_x = options.log_y = true;
  options.x_min = 1e-2, options.x_max = 1e3, options.y_min = 1, options.y_max = 100;
  const PlotFrame frame = plotFrame({}, options);
  const double width = frame.right - frame.left, height = frame.bottom - frame.top;
  EXPECT_NEAR(frame.pixelX(1e-2), frame.left, 1e-9);
  EXPECT_NEAR(frame.pixelX(1e3), frame.right, 1e-9);
  EXPECT_NEAR(frame.pixelX(1), frame.left + 0.4 * width, 1e-9);
  EXPECT_NEAR(frame.pixelX(std::sqrt(10.0)), frame.left + 0.5 * width, 1e-9);
  EXPECT_NEAR(frame.pixelY(10), frame.bottom - 0.5 * height, 1e-9);
  EXPECT_NEAR(frame.pixelY(100), frame.top, 1e-9);
}

TEST(Plot, FitsTheDataWithAMarginAndLogAxesToWholeDecades) {
  const std::vector<PlotSeries> series = {makeSeries("a", {1, 3}, {12, 30}, Vec3(0, 0, 1))};
  PlotOptions options;
  PlotFrame frame = plotFrame(series, options);
  EXPECT_DOUBLE_EQ(frame.x_min, 0.9);
  EXPECT_DOUBLE_EQ(frame.x_max, 3.1);
  EXPECT_DOUBLE_EQ(frame.y_min, 12 - 0.05 * 18);
  EXPECT_DOUBLE_EQ(frame.y_max, 30 + 0.05 * 18);

  options.log_y = true;
  frame = plotFrame(series, options);
  EXPECT_DOUBLE_EQ(frame.y_min, 10);
  EXPECT_DOUBLE_EQ(frame.y_max, 100);
  // Reference lines are part of the fit (a goal line must be visible).
  options.h_lines = {{200, "goal"}};
  frame = plotFrame(series, options);
  EXPECT_DOUBLE_EQ(frame.y_max, 1000);
  // One explicit end, the other fitted.
  options.x_min = 0;
  frame = plotFrame(series, options);
  EXPECT_EQ(frame.x_min, 0);
  EXPECT_DOUBLE_EQ(frame.x_max, 3.1);
}

TEST(Plot, MarkerAppearsAtTheMappedPixel) {
  const Vec3 red(0.9, 0.1, 0.1);
  const PlotOptions options = squareRange(0, 10);
  const std::vector<PlotSeries> series = {makeSeries("", {2.5}, {7.5}, red)};
  const PlotFrame frame = plotFrame(series, options);
  const int px = int(std::lround(frame.pixelX(2.5))), py = int(std::lround(frame.pixelY(7.5)));
  const Image image = renderPlot(series, options);
  // A filled disc of radius 4 around the point, nothing of the colour beyond it.
  EXPECT_TRUE(pixelIs(image, px, py, red));
  EXPECT_TRUE(pixelIs(image, px + 3, py, red));
  EXPECT_TRUE(pixelIs(image, px, py - 4, red));
  EXPECT_TRUE(pixelIs(image, px - 2, py + 2, red));
  EXPECT_FALSE(pixelIs(image, px + 6, py, red));
  EXPECT_FALSE(pixelIs(image, px, py + 6, red));
  const long disc = countPixels(image, red);
  EXPECT_GE(disc, 45);
  EXPECT_LE(disc, 81);
  // The same point elsewhere leaves that pixel alone.
  const Image moved = renderPlot({makeSeries("", {7.5}, {2.5}, red)}, options);
  EXPECT_FALSE(pixelIs(moved, px, py, red));
  EXPECT_TRUE(pixelIs(moved, int(std::lround(frame.pixelX(7.5))),
                      int(std::lround(frame.pixelY(2.5))), red));
}

TEST(Plot, MarkersOnLogAxesLandOnTheLogPixel) {
  const Vec3 green(0.1, 0.6, 0.2);
  PlotOptions options;
  options.log_x = options.log_y = true;
  options.x_min = 1e-3, options.x_max = 10, options.y_min = 1, options.y_max = 1e4;
  const std::vector<PlotSeries> series = {makeSeries("", {0.01}, {100}, green)};
  const PlotFrame frame = plotFrame(series, options);
  const Image image = renderPlot(series, options);
  const int px = int(std::lround(frame.left + 0.25 * (frame.right - frame.left)));
  const int py = int(std::lround(frame.bottom - 0.5 * (frame.bottom - frame.top)));
  EXPECT_TRUE(pixelIs(image, px, py, green));
}

TEST(Plot, EverySeriesColourAppears) {
  const Vec3 orange(0.95, 0.5, 0.1), purple(0.5, 0.2, 0.7);
  const PlotSeries first = makeSeries("FEM", {1, 2, 3}, {1, 4, 9}, orange);
  const PlotSeries second = makeSeries("ROM", {1, 2, 3}, {2, 3, 4}, purple);
  const Image both = renderPlot({first, second});
  EXPECT_GT(countPixels(both, orange), 0);
  EXPECT_GT(countPixels(both, purple), 0);
  const Image only_first = renderPlot({first});
  EXPECT_GT(countPixels(only_first, orange), 0);
  EXPECT_EQ(countPixels(only_first, purple), 0);
}

TEST(Plot, LinesConnectThePointsInOrder) {
  const Vec3 blue(0.1, 0.3, 0.9);
  const PlotOptions options = squareRange(0, 10);
  PlotSeries series = makeSeries("", {1, 9}, {1, 9}, blue);
  series.markers = false;
  series.lines = true;
  const PlotFrame frame = plotFrame({series}, options);
  const int mid_x = int(std::lround(frame.pixelX(5))), mid_y = int(std::lround(frame.pixelY(5)));
  const Image with_line = renderPlot({series}, options);
  // The midpoint lies on the line (Bresenham stays within half a pixel of it).
  bool found = false;
  for (int dy = -1; dy <= 1; ++dy)
    for (int dx = -1; dx <= 1; ++dx)
      found = found || pixelIs(with_line, mid_x + dx, mid_y + dy, blue);
  EXPECT_TRUE(found);
  series.lines = false;
  EXPECT_EQ(countPixels(renderPlot({series}, options), blue), 0);

  // A horizontal series line is 2 px wide.
  PlotSeries flat = makeSeries("", {1, 9}, {5, 5}, blue);
  flat.markers = false;
  flat.lines = true;
  const Image flat_image = renderPlot({flat}, options);
  int column_count = 0;
  for (int y = 0; y < flat_image.height; ++y) column_count += pixelIs(flat_image, mid_x, y, blue);
  EXPECT_EQ(column_count, 2);
}

TEST(Plot, LinesTowardsFarPointsKeepTheirDirection) {
  const Vec3 blue(0.1, 0.3, 0.9);
  const PlotOptions options = squareRange(0, 10);
  // From (5, 5) in direction (1, −0.5), to a point far outside the explicit range.
  PlotSeries series = makeSeries("", {5, 5 + 2e200}, {5, 5 - 1e200}, blue);
  series.markers = false;
  series.lines = true;
  const PlotFrame frame = plotFrame({series}, options);
  const Image image = renderPlot({series}, options);
  for (const double x : {7.0, 9.0}) {
    const int px = int(std::lround(frame.pixelX(x)));
    const int py = int(std::lround(frame.pixelY(5 - 0.5 * (x - 5))));
    bool found = false;
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) found = found || pixelIs(image, px + dx, py + dy, blue);
    EXPECT_TRUE(found) << "x = " << x;
  }
}

TEST(Plot, TitleDrawsInTheTitleAreaOnly) {
  const std::vector<PlotSeries> series = {makeSeries("a", {1, 2}, {1, 2}, Vec3(0, 0, 0.8))};
  PlotOptions options;
  const Image plain = renderPlot(series, options);
  options.title = "Speed vs accuracy";
  const Image titled = renderPlot(series, options);
  const PlotFrame frame = plotFrame(series, options);
  const std::array<int, 4> box = differenceBox(plain, titled);
  ASSERT_GE(box[0], 0) << "the title drew nothing";
  EXPECT_LT(box[3], frame.top);        // entirely above the plot area
  EXPECT_GE(box[3] - box[1] + 1, 12);  // 2× font: 14 rows
  EXPECT_GT(box[2] - box[0], 100);
  // Centred over the plot area.
  EXPECT_NEAR((box[0] + box[2]) / 2.0, (frame.left + frame.right) / 2.0, 3);
}

TEST(Plot, AxisLabelsDrawBelowAndRotatedLeftOfThePlotArea) {
  const std::vector<PlotSeries> series = {makeSeries("a", {1, 2}, {1, 2}, Vec3(0, 0, 0.8))};
  PlotOptions options;
  const Image plain = renderPlot(series, options);
  const PlotFrame frame = plotFrame(series, options);

  options.x_label = "time per frame (ms)";
  const std::array<int, 4> x_box = differenceBox(plain, renderPlot(series, options));
  ASSERT_GE(x_box[0], 0);
  EXPECT_GT(x_box[1], frame.bottom + 15);               // below the tick labels
  EXPECT_GT(x_box[2] - x_box[0], x_box[3] - x_box[1]);  // horizontal text

  options.x_label.clear();
  options.y_label = "vertex error (mm)";
  const std::array<int, 4> y_box = differenceBox(plain, renderPlot(series, options));
  ASSERT_GE(y_box[0], 0);
  EXPECT_LT(y_box[2], frame.left - 8);                        // left of the tick labels
  EXPECT_GT(y_box[3] - y_box[1], 4 * (y_box[2] - y_box[0]));  // rotated: tall and narrow
}

TEST(Plot, CharactersOutsideTheFontDrawAsABox) {
  PlotOptions options;
  options.title = "\x01";
  const Image image = renderPlot({}, options);
  const Image plain = renderPlot({}, PlotOptions());
  const std::array<int, 4> box = differenceBox(plain, image);
  ASSERT_GE(box[0], 0);
  // 5 × 7 outline at scale 2: 10 × 14 pixels, hollow.
  EXPECT_EQ(box[2] - box[0] + 1, 10);
  EXPECT_EQ(box[3] - box[1] + 1, 14);
  EXPECT_TRUE(pixelIs(image, (box[0] + box[2]) / 2, (box[1] + box[3]) / 2, kWhiteBytes));
}

TEST(Plot, LogDecadeTicksAreEquallySpacedAndLabelled) {
  PlotOptions options;
  options.log_x = options.log_y = true;
  options.x_min = 1e-2, options.x_max = 1e3, options.y_min = 1e-5, options.y_max = 1e6;
  const PlotFrame frame = plotFrame({}, options);

  std::vector<double> decade_pixels;
  std::vector<std::string> decade_labels;
  int minor = 0;
  for (const PlotTick& tick : frame.x_ticks) {
    if (tick.major) {
      decade_pixels.push_back(frame.pixelX(tick.value));
      decade_labels.push_back(tick.label);
    } else {
      ++minor;
      EXPECT_TRUE(tick.label.empty());
    }
  }
  EXPECT_EQ(decade_labels, (std::vector<std::string>{"0.01", "0.1", "1", "10", "100", "1000"}));
  EXPECT_EQ(minor, 5 * 8);  // 2..9 in each of the five decades
  ASSERT_EQ(decade_pixels.size(), 6u);
  const double spacing = decade_pixels[1] - decade_pixels[0];
  EXPECT_GT(spacing, 50);
  for (size_t k = 1; k < decade_pixels.size(); ++k) {
    EXPECT_NEAR(decade_pixels[k] - decade_pixels[k - 1], spacing, 1e-9);
  }

  // Beyond 0.01 … 1000 the labels switch to 1e-3 style.
  std::set<std::string> y_labels;
  std::vector<double> y_decades;
  for (const PlotTick& tick : frame.y_ticks) {
    if (!tick.label.empty()) y_labels.insert(tick.label);
    if (tick.major) y_decades.push_back(frame.pixelY(tick.value));
  }
  for (const char* label : {"1e-5", "1e-3", "0.01", "1", "1000", "1e4", "1e6"}) {
    EXPECT_TRUE(y_labels.count(label)) << label;
  }
  ASSERT_EQ(y_decades.size(), 12u);
  for (size_t k = 1; k < y_decades.size(); ++k) {
    EXPECT_NEAR(y_decades[k] - y_decades[k - 1], y_decades[1] - y_decades[0], 1e-9);
  }

  // The image carries the tick marks: long at decades, short at minor ticks.
  const Image image = renderPlot({}, options);
  for (double x : decade_pixels) {
    EXPECT_TRUE(pixelIs(image, int(std::lround(x)), frame.bottom - 5, kBlackBytes));
  }
  const int two = int(std::lround(frame.pixelX(2.0)));
  EXPECT_TRUE(pixelIs(image, two, frame.bottom - 2, kBlackBytes));
  EXPECT_TRUE(pixelIs(image, two, frame.bottom - 5, kWhiteBytes));
}

TEST(Plot, CrowdedLogAxesLabelEveryKthDecade) {
  PlotOptions options;
  options.log_x = true;
  options.x_min = 1e-30, options.x_max = 1e30;
  const PlotFrame frame = plotFrame({}, options);
  std::vector<double> labelled;
  for (const PlotTick& tick : frame.x_ticks) {
    EXPECT_EQ(tick.major, !tick.label.empty());  // unlabelled decades are minor ticks
    if (!tick.label.empty()) labelled.push_back(frame.pixelX(tick.value));
  }
  // Every 2nd, 5th or 10th decade: 0 is among them.
  EXPECT_NE(std::find_if(frame.x_ticks.begin(), frame.x_ticks.end(),
                         [](const PlotTick& tick) { return tick.label == "1"; }),
            frame.x_ticks.end());
  ASSERT_GE(labelled.size(), 3u);
  EXPECT_LT(labelled.size(), 61u);
  for (size_t k = 1; k < labelled.size(); ++k) {
    EXPECT_NEAR(labelled[k] - labelled[k - 1], labelled[1] - labelled[0], 1e-9);
    EXPECT_GE(labelled[k] - labelled[k - 1], 45);  // room for "1e-30"
  }
}

TEST(Plot, ShortLogRangesStillGetLabelledTicks) {
  PlotOptions options;
  options.log_y = true;
  options.y_min = 2, options.y_max = 8;  // no decade inside
  int labelled = 0;
  for (const PlotTick& tick : plotFrame({}, options).y_ticks) labelled += !tick.label.empty();
  EXPECT_GE(labelled, 2);
}

TEST(Plot, LinearTicksUseNiceSteps) {
  PlotOptions options;
  options.x_min = -3.7, options.x_max = 12.2, options.y_min = 0, options.y_max = 0.03;
  const PlotFrame frame = plotFrame({}, options);
  for (const std::vector<PlotTick>* ticks : {&frame.x_ticks, &frame.y_ticks}) {
    ASSERT_GE(ticks->size(), 3u);
    const double step = (*ticks)[1].value - (*ticks)[0].value;
    const double mantissa = step / std::pow(10.0, std::floor(std::log10(step) + 1e-9));
    EXPECT_TRUE(std::abs(mantissa - 1) < 1e-9 || std::abs(mantissa - 2) < 1e-9 ||
                std::abs(mantissa - 5) < 1e-9)
        << "step " << step;
    for (size_t k = 0; k < ticks->size(); ++k) {
      const PlotTick& tick = (*ticks)[k];
      if (k > 0) {
        EXPECT_NEAR(tick.value - (*ticks)[k - 1].value, step, 1e-9 * step);
      }
      // Labels read back as their values.
      EXPECT_NEAR(std::strtod(tick.label.c_str(), nullptr), tick.value, 1e-9 * step) << tick.label;
    }
  }
  EXPECT_EQ(frame.x_ticks.front().label, "-2");
  EXPECT_EQ(frame.y_ticks.front().label, "0");
}

TEST(Plot, LegendShowsASwatchAwayFromTheData) {
  const Vec3 teal(0.1, 0.55, 0.55);
  const PlotOptions options = squareRange(0, 10);
  // Points crowd the top-right corner, where the legend would go first.
  PlotSeries series = makeSeries("", {9.5, 9.8, 9.2}, {9.5, 9.1, 9.7}, teal);
  const long without_legend = countPixels(renderPlot({series}, options), teal);
  series.label = "skeleton";
  const Image with_legend = renderPlot({series}, options);
  EXPECT_EQ(countPixels(with_legend, teal) - without_legend, 14 * 7);  // the swatch, whole
  const PlotFrame frame = plotFrame({series}, options);
  EXPECT_TRUE(pixelIs(with_legend, int(std::lround(frame.pixelX(9.5))),
                      int(std::lround(frame.pixelY(9.5))), teal));
}

TEST(Plot, ReferenceLinesAreDashed) {
  PlotOptions options = squareRange(0, 10);
  options.h_lines = {{5, ""}};
  const PlotFrame frame = plotFrame({}, options);
  const Image image = renderPlot({}, options);
  const int y = int(std::lround(frame.pixelY(5)));
  int drawn = 0, gaps = 0;
  for (int x = frame.left + 1; x < frame.right; ++x) {
    if (pixelIs(image, x, y, kWhiteBytes)) {
      ++gaps;
    } else if (!pixelIs(image, x, y, kGridBytes)) {  // grid lines cross it
      ++drawn;
    }
  }
  EXPECT_GT(drawn, 100);
  EXPECT_GT(gaps, 100);
}

TEST(Plot, InvalidInputsThrowNamingTheSeriesAndField) {
  const PlotSeries good = makeSeries("FEM", {1, 2, 3}, {1, 2, 3}, Vec3(0.2, 0.4, 0.8));
  const auto messageFor = [&](const PlotSeries& bad, const PlotOptions& options = {}) {
    return test::messageOf<InputError>([&] { plotFrame({good, bad}, options); });
  };
  const auto expectNames = [](const std::string& message, std::vector<std::string> parts) {
    for (const std::string& part : parts) {
      EXPECT_NE(message.find(part), std::string::npos) << "'" << part << "' not in: " << message;
    }
  };
  PlotSeries bad = good;
  bad.label = "ROM";
  bad.y = {1, 2};
  expectNames(messageFor(bad), {"series 1", "ROM", "x has 3", "y has 2"});
  bad.x.clear(), bad.y.clear();
  expectNames(messageFor(bad), {"series 1", "x has 0"});
  bad = good;
  bad.x[1] = kNaN;
  expectNames(messageFor(bad), {"series 1", "x[1]", "finite"});
  bad = good;
  bad.y[0] = kInf;
  expectNames(messageFor(bad), {"series 1", "y[0]", "inf"});
  bad = good;
  bad.x[2] = 0;
  PlotOptions log_x;
  log_x.log_x = true;
  expectNames(messageFor(bad, log_x), {"series 1", "x[2] = 0", "log x"});
  bad = good;
  bad.y[1] = -2;
  PlotOptions log_y;
  log_y.log_y = true;
  expectNames(messageFor(bad, log_y), {"series 1", "y[1] = -2", "log y"});
  bad = good;
  bad.point_labels = {"a", "b"};
  expectNames(messageFor(bad), {"series 1", "point_labels has 2", "3"});
  bad = good;
  bad.color = Vec3(0.5, 1.5, 0);
  expectNames(messageFor(bad), {"series 1", "color", "1.5"});

  PlotOptions options;
  options.width = 199;
  expectNames(messageFor(good, options), {"width = 199", "200"});
  options = {};
  options.height = 8001;
  expectNames(messageFor(good, options), {"height = 8001", "8000"});
  options = {};
  options.x_min = 5, options.x_max = 5;
  expectNames(messageFor(good, options), {"x_min = 5", "x_max = 5"});
  options = {};
  options.y_min = 7, options.y_max = 2;
  expectNames(messageFor(good, options), {"y_min = 7", "y_max = 2"});
  options = {};
  options.y_min = 10;  // above the data: the fitted upper end is below it
  expectNames(messageFor(good, options), {"y_min = 10", "fitted y_max"});
  options = {};
  options.log_y = true;
  options.y_min = 0, options.y_max = 10;
  expectNames(messageFor(good, options), {"y_min = 0", "log y"});
  options = {};
  options.log_x = true;
  options.x_max = -1;
  expectNames(messageFor(good, options), {"x_max = -1", "log x"});
  options = {};
  options.x_max = kInf;
  expectNames(messageFor(good, options), {"x_max = inf"});
  options = {};
  options.h_lines = {{kNaN, "goal"}};
  expectNames(messageFor(good, options), {"h_lines[0]", "nan"});
  options = {};
  options.log_x = true;
  options.v_lines = {{1, ""}, {-1, ""}};
  expectNames(messageFor(good, options), {"v_lines[1] = -1", "log x"});
  options = {};
  options.x_min = 1, options.x_max = 1 + 1e-15;
  expectNames(messageFor(good, options), {"x range", "precision"});

  // renderPlot validates the same way.
  bad = good;
  bad.x[0] = kNaN;
  expectNames(test::messageOf<InputError>([&] { renderPlot({good, bad}); }), {"series 1", "x[0]"});
}

TEST(Plot, PngRoundTripKeepsThePixels) {
  PlotSeries fem = makeSeries("FEM", {120, 45, 20}, {0.4, 1.1, 2.5}, Vec3(0.85, 0.3, 0.1));
  fem.lines = true;
  fem.point_labels = {"fine", "medium", "coarse"};
  PlotSeries rom = makeSeries("ROM", {8, 4, 2}, {1.5, 2.8, 5.0}, Vec3(0.2, 0.4, 0.8));
  rom.lines = true;
  PlotSeries skeleton = makeSeries("skeleton", {0.3}, {9.0}, Vec3(0.3, 0.6, 0.3));
  PlotOptions options;
  options.title = "Speed vs accuracy";
  options.x_label = "time per frame (ms)";
  options.y_label = "surface error (mm)";
  options.log_x = options.log_y = true;
  options.h_lines = {{3.0, "goal: 3 mm"}};
  options.v_lines = {{33.3, "real time (30 fps)"}};
  const Image image = renderPlot({fem, rom, skeleton}, options);

  const std::string path = test::freshTempDir("plot") + "/speed_accuracy.png";
  writePng(path, image);
  const Image read = readPng(path);
  ASSERT_EQ(read.width, image.width);
  ASSERT_EQ(read.height, image.height);
  EXPECT_TRUE(read.rgb == image.rgb);
}

}  // namespace
}  // namespace flsh::render
