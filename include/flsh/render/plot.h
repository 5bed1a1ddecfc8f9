// A small scatter/line plot renderer into RGB images (e.g. the speed–accuracy figure of the
// benchmarks): axes with linear or logarithmic scales, ticks and grid, reference lines, point
// labels and a legend, with a built-in 5 × 7 pixel font. No dependencies beyond the Image type.
#pragma once

#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "flsh/core/types.h"
#include "flsh/render/render.h"

namespace flsh::render {

/// One data series of a plot.
struct PlotSeries {
  std::string label;                 ///< legend text (printable ASCII; empty = not in the legend)
  std::vector<double> x, y;          ///< same length ≥ 1, finite (> 0 on a log axis), data units
  Vec3 color = Vec3(0.2, 0.4, 0.8);  ///< sRGB in [0, 1]
  bool lines = false;                ///< connect the points in order (2 px wide)
  bool markers = true;               ///< filled circle (radius 4 px) per point
  /// Empty, or one short text per point, drawn to the right of the point.
  std::vector<std::string> point_labels;
};

struct PlotOptions {
  int width = 900, height = 600;        ///< pixels, each in [200, 8000]
  std::string title, x_label, y_label;  ///< the y label is drawn rotated (reads bottom to top)
  bool log_x = false, log_y = false;
  /// Axis ranges in data units; NaN = fit the data and the reference lines with a 5 % margin
  /// (log axes: whole decades around them). Either end may be given alone.
  double x_min = std::numeric_limits<double>::quiet_NaN();
  double x_max = std::numeric_limits<double>::quiet_NaN();
  double y_min = std::numeric_limits<double>::quiet_NaN();
  double y_max = std::numeric_limits<double>::quiet_NaN();
  /// Horizontal (at y) / vertical (at x) reference lines, e.g. a goal: value in data units and
  /// an optional label; drawn dashed.
  std::vector<std::pair<double, std::string>> h_lines, v_lines;
};

/// One tick mark of an axis.
struct PlotTick {
  double value = 0;   ///< data units
  std::string label;  ///< empty for unlabelled (minor) ticks
  bool major = true;  ///< major ticks are longer and carry a grid line
};

/// The layout of a plot: where the plot area lies in the image, the resolved axis ranges and
/// the ticks, i.e. the data → pixel transform that renderPlot uses.
struct PlotFrame {
  int width = 0, height = 0;  ///< image size, pixels
  /// Plot area: pixel columns left..right and rows top..bottom (inclusive, row 0 at the top);
  /// the axes box is drawn on these four lines.
  int left = 0, right = 0, top = 0, bottom = 0;
  double x_min = 0, x_max = 1, y_min = 0, y_max = 1;  ///< resolved axis ranges, data units
  bool log_x = false, log_y = false;
  std::vector<PlotTick> x_ticks, y_ticks;  ///< ascending values, all inside the ranges

  /// Pixel column of data value x (x_min → left, x_max → right; log-linear on a log axis;
  /// values outside the range map outside the box). x must be > 0 on a log axis.
  double pixelX(double x) const;
  /// Pixel row of data value y (y_min → bottom, y_max → top).
  double pixelY(double y) const;
};

/// Validates `series` and `options` and computes the layout renderPlot uses. Throws InputError
/// naming the series index and field (x/y size mismatch or empty, non-finite values,
/// non-positive values on a log axis, point_labels of the wrong length, colour outside
/// [0, 1]) or the option (width/height outside [200, 8000], a range with min ≥ max, a
/// non-finite range end, a range end ≤ 0 on a log axis, a non-finite or, on a log axis,
/// non-positive reference line).
PlotFrame plotFrame(const std::vector<PlotSeries>& series, const PlotOptions& options = {});

/// Renders the plot (white background, axes box, ticks, grid, labels, title, reference lines,
/// series, legend in the emptiest corner of the plot area). Same errors as plotFrame.
Image renderPlot(const std::vector<PlotSeries>& series, const PlotOptions& options = {});

/// Draws `text` in the plots' 5 × 7 pixel font, each font pixel a `scale` × `scale` block, with
/// its top-left corner at pixel (x, y) (row 0 at the top); pixels outside the image are
/// clipped. Characters outside printable ASCII are drawn as an empty box. `color` is sRGB in
/// [0, 1] (clamped). Throws InputError for scale < 1 or > 16.
void drawLabel(Image& image, int x, int y, const std::string& text,
               const Vec3& color = Vec3(0.1, 0.1, 0.1), int scale = 1);
/// Width and height in pixels of `text` as drawLabel draws it (width 0 for empty text; the
/// height of one line, descenders of g, p, q, y excluded).
int labelWidth(const std::string& text, int scale = 1);
int labelHeight(int scale = 1);

}  // namespace flsh::render
