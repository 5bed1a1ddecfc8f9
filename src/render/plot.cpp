// Scatter/line plots into RGB images: layout (PlotFrame), ticks, a 5 × 7 bitmap font and
// aliased line, circle and text rasterization.
#include "flsh/render/plot.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "flsh/core/error.h"

namespace flsh::render {
namespace {

// ---------------------------------------------------------------------------------------------
// Font: printable ASCII 32..126, 5 columns × 7 rows per glyph; each row is one byte whose bits
// 4..0 are the columns from left to right. Characters are advanced by 6 pixels.
constexpr int kGlyphWidth = 5, kGlyphHeight = 7, kGlyphAdvance = 6;
using Glyph = std::array<uint8_t, kGlyphHeight>;

constexpr Glyph kFont[95] = {
    {0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00},  // ' '
    {0x04, 0x04, 0x04, 0x04, 0x04, 0x00, 0x04},  // !
    {0x0A, 0x0A, 0x00, 0x00, 0x00, 0x00, 0x00},  // "
    {0x0A, 0x0A, 0x1F, 0x0A, 0x1F, 0x0A, 0x0A},  // #
    {0x04, 0x0F, 0x14, 0x0E, 0x05, 0x1E, 0x04},  // $
    {0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03},  // %
    {0x0C, 0x12, 0x14, 0x08, 0x15, 0x12, 0x0D},  // &
    {0x04, 0x04, 0x00, 0x00, 0x00, 0x00, 0x00},  // '
    {0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02},  // (
    {0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08},  // )
    {0x00, 0x04, 0x15, 0x0E, 0x15, 0x04, 0x00},  // *
    {0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00},  // +
    {0x00, 0x00, 0x00, 0x00, 0x0C, 0x04, 0x08},  // ,
    {0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00},  // -
    {0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C},  // .
    {0x00, 0x01, 0x02, 0x04, 0x08, 0x10, 0x00},  // /
    {0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E},  // 0
    {0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E},  // 1
    {0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F},  // 2
    {0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E},  // 3
    {0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02},  // 4
    {0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E},  // 5
    {0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E},  // 6
    {0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08},  // 7
    {0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E},  // 8
    {0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C},  // 9
    {0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00},  // :
    {0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x04, 0x08},  // ;
    {0x02, 0x04, 0x08, 0x10, 0x08, 0x04, 0x02},  // <
    {0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00},  // =
    {0x08, 0x04, 0x02, 0x01, 0x02, 0x04, 0x08},  // >
    {0x0E, 0x11, 0x01, 0x02, 0x04, 0x00, 0x04},  // ?
    {0x0E, 0x11, 0x01, 0x0D, 0x15, 0x15, 0x0E},  // @
    {0x0E, 0x11, 0x11, 0x11, 0x1F, 0x11, 0x11},  // A
    {0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E},  // B
    {0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E},  // C
    {0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C},  // D
    {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F},  // E
    {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10},  // F
    {0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F},  // G
    {0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11},  // H
    {0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E},  // I
    {0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C},  // J
    {0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11},  // K
    {0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F},  // L
    {0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11},  // M
    {0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11},  // N
    {0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E},  // O
    {0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10},  // P
    {0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D},  // Q
    {0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11},  // R
    {0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E},  // S
    {0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04},  // T
    {0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E},  // U
    {0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04},  // V
    {0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A},  // W
    {0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11},  // X
    {0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04},  // Y
    {0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F},  // Z
    {0x0E, 0x08, 0x08, 0x08, 0x08, 0x08, 0x0E},  // [
    {0x00, 0x10, 0x08, 0x04, 0x02, 0x01, 0x00},  // backslash
    {0x0E, 0x02, 0x02, 0x02, 0x02, 0x02, 0x0E},  // ]
    {0x04, 0x0A, 0x11, 0x00, 0x00, 0x00, 0x00},  // ^
    {0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x1F},  // _
    {0x08, 0x04, 0x02, 0x00, 0x00, 0x00, 0x00},  // `
    {0x00, 0x00, 0x0E, 0x01, 0x0F, 0x11, 0x0F},  // a
    {0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x1E},  // b
    {0x00, 0x00, 0x0E, 0x10, 0x10, 0x11, 0x0E},  // c
    {0x01, 0x01, 0x0D, 0x13, 0x11, 0x11, 0x0F},  // d
    {0x00, 0x00, 0x0E, 0x11, 0x1F, 0x10, 0x0E},  // e
    {0x06, 0x09, 0x08, 0x1C, 0x08, 0x08, 0x08},  // f
    {0x0F, 0x11, 0x11, 0x11, 0x0F, 0x01, 0x0E},  // g (descends)
    {0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x11},  // h
    {0x04, 0x00, 0x0C, 0x04, 0x04, 0x04, 0x0E},  // i
    {0x02, 0x00, 0x06, 0x02, 0x02, 0x12, 0x0C},  // j
    {0x10, 0x10, 0x12, 0x14, 0x18, 0x14, 0x12},  // k
    {0x0C, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E},  // l
    {0x00, 0x00, 0x1A, 0x15, 0x15, 0x11, 0x11},  // m
    {0x00, 0x00, 0x16, 0x19, 0x11, 0x11, 0x11},  // n
    {0x00, 0x00, 0x0E, 0x11, 0x11, 0x11, 0x0E},  // o
    {0x1E, 0x11, 0x11, 0x11, 0x1E, 0x10, 0x10},  // p (descends)
    {0x0F, 0x11, 0x11, 0x11, 0x0F, 0x01, 0x01},  // q (descends)
    {0x00, 0x00, 0x16, 0x19, 0x10, 0x10, 0x10},  // r
    {0x00, 0x00, 0x0E, 0x10, 0x0E, 0x01, 0x1E},  // s
    {0x08, 0x08, 0x1C, 0x08, 0x08, 0x09, 0x06},  // t
    {0x00, 0x00, 0x11, 0x11, 0x11, 0x13, 0x0D},  // u
    {0x00, 0x00, 0x11, 0x11, 0x11, 0x0A, 0x04},  // v
    {0x00, 0x00, 0x11, 0x11, 0x15, 0x15, 0x0A},  // w
    {0x00, 0x00, 0x11, 0x0A, 0x04, 0x0A, 0x11},  // x
    {0x11, 0x11, 0x11, 0x11, 0x0F, 0x01, 0x0E},  // y (descends)
    {0x00, 0x00, 0x1F, 0x02, 0x04, 0x08, 0x1F},  // z
    {0x02, 0x04, 0x04, 0x08, 0x04, 0x04, 0x02},  // {
    {0x04, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04},  // |
    {0x08, 0x04, 0x04, 0x02, 0x04, 0x04, 0x08},  // }
    {0x00, 0x00, 0x08, 0x15, 0x02, 0x00, 0x00},  // ~
};
// Drawn for characters outside 32..126: an empty box, so that missing glyphs are visible.
constexpr Glyph kMissingGlyph = {0x1F, 0x11, 0x11, 0x11, 0x11, 0x11, 0x1F};

// Rows by which a glyph is drawn lower than the others: g, p, q, y hang below the baseline.
int glyphDrop(char c) { return c == 'g' || c == 'p' || c == 'q' || c == 'y' ? 2 : 0; }

const Glyph& glyphOf(char c) {
  const int code = static_cast<unsigned char>(c);
  return code >= 32 && code <= 126 ? kFont[code - 32] : kMissingGlyph;
}

/// Width in pixels of `text` at `scale` (0 for empty text). Texts are laid out by the 7-row
/// cell; descenders hang 2 rows below it.
int textWidth(const std::string& text, int scale = 1) {
  return text.empty() ? 0 : (int(text.size()) * kGlyphAdvance - 1) * scale;
}
int textHeight(int scale = 1) { return kGlyphHeight * scale; }

// ---------------------------------------------------------------------------------------------
// Layout constants, pixels. The margins around the plot area are fixed where possible so that
// optional texts (title, axis labels) do not move the axes.
constexpr int kTopMargin = 44;  // title (2× font) at row kTitleRow
constexpr int kTitleRow = 12;
constexpr int kBottomMargin = 42;  // tick labels, then the x label
constexpr int kRightMarginMin = 24;
constexpr int kYLabelColumn = 10;  // left edge of the rotated y label
constexpr int kMajorTickLength = 6, kMinorTickLength = 3;
constexpr int kTickLabelGap = 8;  // from the axis line to the tick label
constexpr int kMarkerRadius = 4;
// Least distance between labelled decades: x labels ("1e-12") sit side by side, y labels
// are stacked.
constexpr int kXLabelSpacing = 45, kYLabelSpacing = 20;
constexpr int kMinImageSize = 200, kMaxImageSize = 8000;
// Lines are clipped in unrounded pixel coordinates, which keeps the direction towards points
// far outside an explicit range; only overflowed (infinite) coordinates are clamped, to this.
constexpr double kCoordinateLimit = 1e300;
// Marker centres are rounded to int: clamp them first (markers this far out are clipped anyway).
constexpr double kMarkerCoordinateLimit = 1e7;

std::string numberText(double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "%.10g", value);
  return buffer;
}

// "2.5e-05" → "2.5e-5", "1e+07" → "1e7": shorter tick labels.
std::string compactExponent(const std::string& text) {
  const size_t e = text.find('e');
  if (e == std::string::npos) return text;
  const int exponent = std::stoi(text.substr(e + 1));
  return text.substr(0, e) + "e" + std::to_string(exponent);
}

// ---------------------------------------------------------------------------------------------
// Ticks.

// Labels of linear ticks k · step: fixed-point with as many decimals as the step needs, or
// mantissa/exponent form for very large or very small numbers.
std::string linearTickLabel(double value, double step, double max_abs) {
  if (value == 0) return "0";
  char buffer[64];
  if (step >= 1e-4 && max_abs < 1e6) {
    const int decimals = std::max(0, int(std::ceil(-std::log10(step) - 1e-9)));
    std::snprintf(buffer, sizeof(buffer), "%.*f", decimals, value);
    return buffer;
  }
  const int digits = std::max(
      0, int(std::floor(std::log10(std::abs(value)))) - int(std::floor(std::log10(step) + 1e-9)));
  std::snprintf(buffer, sizeof(buffer), "%.*e", std::min(digits, 16), value);
  return compactExponent(buffer);
}

// "Nice" ticks (1-2-5 steps) over [lo, hi], about one per 90 pixels.
std::vector<PlotTick> linearTicks(double lo, double hi, int pixels) {
  const double target = std::max(2, pixels / 90);
  const double raw = (hi - lo) / target;
  const double magnitude = std::pow(10.0, std::floor(std::log10(raw)));
  const double residual = raw / magnitude;
  const double step = magnitude * (residual < 1.5   ? 1
                                   : residual < 3.5 ? 2
                                   : residual < 7.5 ? 5
                                                    : 10);
  const double first = std::ceil(lo / step - 1e-9), last = std::floor(hi / step + 1e-9);
  const double max_abs = std::max(std::abs(lo), std::abs(hi));
  std::vector<PlotTick> ticks;
  // The range check of plotFrame keeps (last − first) small; the bound is a safety net.
  for (double k = first; k <= last && ticks.size() < 1000; k += 1) {
    const double value = k * step;
    ticks.push_back({value, linearTickLabel(value, step, max_abs), true});
  }
  return ticks;
}

std::string decadeLabel(int exponent) {
  if (exponent >= 0 && exponent <= 3) return "1" + std::string(exponent, '0');
  if (exponent < 0 && exponent >= -2) return "0." + std::string(-exponent - 1, '0') + "1";
  return "1e" + std::to_string(exponent);
}

std::string generalLabel(double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "%g", value);
  return compactExponent(buffer);
}

// Decade ticks (labelled and major; only every k-th when closer than `label_spacing` pixels),
// minor ticks 2..9 per decade when a decade is wide enough; ranges shorter than two decades
// also label their minor ticks.
std::vector<PlotTick> logTicks(double lo, double hi, int pixels, int label_spacing) {
  const double log_lo = std::log10(lo), log_hi = std::log10(hi);
  const double pixels_per_decade = pixels / (log_hi - log_lo);
  const auto inside = [&](double value) {
    const double t = std::log10(value);
    return t >= log_lo - 1e-9 && t <= log_hi + 1e-9;
  };
  const int first_decade = int(std::ceil(log_lo - 1e-9)),
            last_decade = int(std::floor(log_hi + 1e-9));
  const int decades = std::max(0, last_decade - first_decade + 1);
  const int max_labels = std::max(2, pixels / label_spacing);
  // Label every 1, 2, 5, 10, 20, 50, … decades: the fewest that keeps labels apart.
  const int needed = std::max(1, (decades + max_labels - 1) / max_labels);
  int label_every = 1;
  for (int magnitude = 1; label_every < needed; magnitude *= 10) {
    for (const int factor : {1, 2, 5, 10}) {
      label_every = factor * magnitude;
      if (label_every >= needed) break;
    }
  }
  std::vector<PlotTick> ticks;
  int labelled = 0;
  for (int d = first_decade; d <= last_decade; ++d) {
    // Labelled decades are major (long tick, grid line); the others are minor ticks, dropped
    // where they would merge into a solid band.
    if (((d % label_every) + label_every) % label_every == 0) {
      ticks.push_back({std::pow(10.0, d), decadeLabel(d), true});
      ++labelled;
    } else if (pixels_per_decade >= 4) {
      ticks.push_back({std::pow(10.0, d), "", false});
    }
  }
  const bool label_minor = labelled < 2;
  if (pixels_per_decade >= 30 || label_minor) {
    for (int d = int(std::floor(log_lo)); d <= int(std::floor(log_hi)); ++d) {
      for (int m = 2; m <= 9; ++m) {
        const double value = m * std::pow(10.0, d);
        if (!inside(value)) continue;
        ticks.push_back({value, label_minor ? generalLabel(value) : "", label_minor});
        labelled += label_minor;
      }
    }
  }
  if (labelled < 2) {
    // Less than one minor interval (e.g. [2.1, 2.9]): label linear nice ticks instead.
    for (const PlotTick& tick : linearTicks(lo, hi, pixels)) {
      if (tick.value > 0 && inside(tick.value)) ticks.push_back(tick);
    }
  }
  std::sort(ticks.begin(), ticks.end(),
            [](const PlotTick& a, const PlotTick& b) { return a.value < b.value; });
  return ticks;
}

// ---------------------------------------------------------------------------------------------
// Validation and ranges.

std::string seriesName(const std::vector<PlotSeries>& series, size_t index) {
  std::string name = "plot series " + std::to_string(index);
  if (!series[index].label.empty()) name += " (\"" + series[index].label + "\")";
  return name;
}

void validateValues(const std::vector<PlotSeries>& series, size_t index, const char* field,
                    const std::vector<double>& values, bool log_axis) {
  for (size_t j = 0; j < values.size(); ++j) {
    if (!std::isfinite(values[j])) {
      throw InputError(seriesName(series, index) + ": " + field + "[" + std::to_string(j) +
                       "] = " + numberText(values[j]) + "; expected a finite value");
    }
    if (log_axis && values[j] <= 0) {
      throw InputError(seriesName(series, index) + ": " + field + "[" + std::to_string(j) +
                       "] = " + numberText(values[j]) + " on a log " + field +
                       " axis; expected a value > 0");
    }
  }
}

void validateSeries(const std::vector<PlotSeries>& series, const PlotOptions& options) {
  for (size_t i = 0; i < series.size(); ++i) {
    const PlotSeries& s = series[i];
    if (s.x.empty() || s.x.size() != s.y.size()) {
      throw InputError(seriesName(series, i) + ": x has " + std::to_string(s.x.size()) +
                       " values and y has " + std::to_string(s.y.size()) +
                       "; expected the same number of values, at least 1");
    }
    validateValues(series, i, "x", s.x, options.log_x);
    validateValues(series, i, "y", s.y, options.log_y);
    if (!s.point_labels.empty() && s.point_labels.size() != s.x.size()) {
      throw InputError(seriesName(series, i) + ": point_labels has " +
                       std::to_string(s.point_labels.size()) + " entries; expected 0 or " +
                       std::to_string(s.x.size()) + " (one per point)");
    }
    for (int c = 0; c < 3; ++c) {
      if (!(s.color[c] >= 0 && s.color[c] <= 1)) {
        throw InputError(seriesName(series, i) + ": color = (" + numberText(s.color[0]) + ", " +
                         numberText(s.color[1]) + ", " + numberText(s.color[2]) +
                         "); expected sRGB components in [0, 1]");
      }
    }
  }
}

void validateReferenceLines(const std::vector<std::pair<double, std::string>>& lines,
                            const char* field, const char* axis, bool log_axis) {
  for (size_t j = 0; j < lines.size(); ++j) {
    const double value = lines[j].first;
    const std::string name = std::string("plot options: ") + field + "[" + std::to_string(j) + "]";
    if (!std::isfinite(value)) {
      throw InputError(name + " = " + numberText(value) + "; expected a finite " + axis + " value");
    }
    if (log_axis && value <= 0) {
      throw InputError(name + " = " + numberText(value) + " on a log " + axis +
                       " axis; expected a value > 0");
    }
  }
}

struct AxisRange {
  double lo, hi;
};

// Resolves one axis range: explicit ends where given, otherwise fitted to `values` (data and
// reference lines) with a 5 % margin, or whole decades on a log axis.
AxisRange resolveRange(const char* axis, bool log_axis, double explicit_min, double explicit_max,
                       const std::vector<double>& values) {
  const std::string min_name = std::string(axis) + "_min", max_name = std::string(axis) + "_max";
  const std::array<std::pair<std::string, double>, 2> ends = {
      {{min_name, explicit_min}, {max_name, explicit_max}}};
  for (const auto& [name, value] : ends) {
    if (std::isnan(value)) continue;
    if (!std::isfinite(value)) {
      throw InputError("plot options: " + name + " = " + numberText(value) +
                       "; expected a finite value, or NaN to fit the data");
    }
    if (log_axis && value <= 0) {
      throw InputError("plot options: " + name + " = " + numberText(value) + " on a log " + axis +
                       " axis; expected a value > 0");
    }
  }
  AxisRange fitted = log_axis ? AxisRange{1, 10} : AxisRange{0, 1};
  if (!values.empty()) {
    const auto [min_it, max_it] = std::minmax_element(values.begin(), values.end());
    const double data_min = *min_it, data_max = *max_it;
    if (log_axis) {
      fitted = {std::pow(10.0, std::floor(std::log10(data_min))),
                std::pow(10.0, std::ceil(std::log10(data_max)))};
      if (fitted.lo == fitted.hi) fitted = {fitted.lo / 10, fitted.hi * 10};
    } else {
      const double span = data_max - data_min;
      const double margin = span > 0 ? 0.05 * span : data_min != 0 ? 0.1 * std::abs(data_min) : 1.0;
      fitted = {data_min - margin, data_max + margin};
    }
  }
  const bool has_min = !std::isnan(explicit_min), has_max = !std::isnan(explicit_max);
  const AxisRange range{has_min ? explicit_min : fitted.lo, has_max ? explicit_max : fitted.hi};
  if (!(range.lo < range.hi)) {
    const std::string min_text =
        (has_min ? "" : "fitted ") + min_name + " = " + numberText(range.lo);
    const std::string max_text =
        (has_max ? "" : "fitted ") + max_name + " = " + numberText(range.hi);
    throw InputError("plot options: " + min_text + " is not below " + max_text + "; expected " +
                     min_name + " < " + max_name);
  }
  const double t_lo = log_axis ? std::log10(range.lo) : range.lo;
  const double t_hi = log_axis ? std::log10(range.hi) : range.hi;
  // Ticks and the pixel transform need a span that double precision resolves.
  if (!std::isfinite(t_hi - t_lo) ||
      t_hi - t_lo <= 1e-12 * std::max(std::abs(t_lo), std::abs(t_hi))) {
    throw InputError("plot options: the " + std::string(axis) + " range [" + numberText(range.lo) +
                     ", " + numberText(range.hi) +
                     "] is too wide or too narrow for double precision");
  }
  return range;
}

std::vector<double> axisValues(const std::vector<PlotSeries>& series,
                               const std::vector<std::pair<double, std::string>>& lines,
                               bool x_axis) {
  std::vector<double> values;
  for (const PlotSeries& s : series) {
    const std::vector<double>& v = x_axis ? s.x : s.y;
    values.insert(values.end(), v.begin(), v.end());
  }
  for (const auto& line : lines) values.push_back(line.first);
  return values;
}

int widestLabel(const std::vector<PlotTick>& ticks) {
  int widest = 0;
  for (const PlotTick& tick : ticks) widest = std::max(widest, textWidth(tick.label));
  return widest;
}

// ---------------------------------------------------------------------------------------------
// Rasterization.

struct Rgb {
  uint8_t r, g, b;
};

Rgb toRgb(const Vec3& color) {
  const auto channel = [](double c) { return uint8_t(std::lround(std::clamp(c, 0.0, 1.0) * 255)); };
  return {channel(color[0]), channel(color[1]), channel(color[2])};
}

const Rgb kWhite{255, 255, 255}, kAxisColor{0, 0, 0}, kTextColor{25, 25, 25},
    kGridColor{225, 225, 225}, kReferenceColor{90, 90, 90}, kLegendBorder{80, 80, 80};

// Pixel rectangle, inclusive.
struct Box {
  int x0, y0, x1, y1;
  bool contains(int x, int y) const { return x >= x0 && x <= x1 && y >= y0 && y <= y1; }
};

class Canvas {
 public:
  explicit Canvas(Image& image) : image_(image) {}

  Box bounds() const { return {0, 0, image_.width - 1, image_.height - 1}; }

  void set(int x, int y, Rgb color, const Box& clip) {
    if (!clip.contains(x, y) || !bounds().contains(x, y)) return;
    uint8_t* p = image_.pixel(x, y);
    p[0] = color.r, p[1] = color.g, p[2] = color.b;
  }

  void fillRect(const Box& box, Rgb color) {
    for (int y = box.y0; y <= box.y1; ++y)
      for (int x = box.x0; x <= box.x1; ++x) set(x, y, color, bounds());
  }

  void fillCircle(int cx, int cy, int radius, Rgb color, const Box& clip) {
    // r² + r gives rounder small discs than r².
    const int limit = radius * radius + radius;
    for (int dy = -radius; dy <= radius; ++dy)
      for (int dx = -radius; dx <= radius; ++dx)
        if (dx * dx + dy * dy <= limit) set(cx + dx, cy + dy, color, clip);
  }

  // Line from (x0, y0) to (x1, y1) (pixel coordinates), clipped to `clip`; `thickness` 1 or 2;
  // dash_on > 0 draws dash_on pixels, skips dash_off, measured along the major axis.
  void line(double x0, double y0, double x1, double y1, Rgb color, const Box& clip,
            int thickness = 1, int dash_on = 0, int dash_off = 0) {
    x0 = std::clamp(x0, -kCoordinateLimit, kCoordinateLimit);
    x1 = std::clamp(x1, -kCoordinateLimit, kCoordinateLimit);
    y0 = std::clamp(y0, -kCoordinateLimit, kCoordinateLimit);
    y1 = std::clamp(y1, -kCoordinateLimit, kCoordinateLimit);
    if (!clipSegment(x0, y0, x1, y1, clip)) return;
    int ax = int(std::lround(x0)), ay = int(std::lround(y0));
    const int bx = int(std::lround(x1)), by = int(std::lround(y1));
    const int dx = std::abs(bx - ax), dy = -std::abs(by - ay);
    const int sx = ax < bx ? 1 : -1, sy = ay < by ? 1 : -1;
    const bool x_major = dx >= -dy;
    int error = dx + dy;
    for (int step = 0;; ++step) {
      if (dash_on <= 0 || step % (dash_on + dash_off) < dash_on) {
        set(ax, ay, color, clip);
        // The second pixel goes across the line: below an x-major line, right of a y-major one.
        if (thickness > 1) set(ax + (x_major ? 0 : 1), ay + (x_major ? 1 : 0), color, clip);
      }
      if (ax == bx && ay == by) break;
      const int doubled = 2 * error;
      if (doubled >= dy) error += dy, ax += sx;
      if (doubled <= dx) error += dx, ay += sy;
    }
  }

  // Text with its top-left corner at (x, y); rotated texts read bottom to top and have their
  // bottom-left corner at (x, y).
  void text(int x, int y, const std::string& text, Rgb color, int scale = 1, bool rotated = false) {
    for (size_t i = 0; i < text.size(); ++i) {
      const Glyph& glyph = glyphOf(text[i]);
      const int drop = glyphDrop(text[i]);
      for (int row = 0; row < kGlyphHeight; ++row) {
        for (int column = 0; column < kGlyphWidth; ++column) {
          if (!(glyph[row] & (0x10 >> column))) continue;
          for (int sy = 0; sy < scale; ++sy) {
            for (int sx = 0; sx < scale; ++sx) {
              const int along = (int(i) * kGlyphAdvance + column) * scale + sx;
              const int across = (row + drop) * scale + sy;
              if (rotated) {
                set(x + across, y - along, color, bounds());
              } else {
                set(x + along, y + across, color, bounds());
              }
            }
          }
        }
      }
    }
  }

 private:
  // Liang–Barsky clipping of a segment to a box (inclusive pixel centres).
  static bool clipSegment(double& x0, double& y0, double& x1, double& y1, const Box& box) {
    const double dx = x1 - x0, dy = y1 - y0;
    double t0 = 0, t1 = 1;
    const double p[4] = {-dx, dx, -dy, dy};
    const double q[4] = {x0 - box.x0, box.x1 - x0, y0 - box.y0, box.y1 - y0};
    for (int k = 0; k < 4; ++k) {
      if (p[k] == 0) {
        if (q[k] < 0) return false;
        continue;
      }
      const double t = q[k] / p[k];
      if (p[k] < 0) {
        t0 = std::max(t0, t);
      } else {
        t1 = std::min(t1, t);
      }
      if (t0 > t1) return false;
    }
    const double cx0 = x0 + t0 * dx, cy0 = y0 + t0 * dy;
    x1 = x0 + t1 * dx, y1 = y0 + t1 * dy;
    x0 = cx0, y0 = cy0;
    return true;
  }

  Image& image_;
};

int roundPixel(double coordinate) {
  return int(std::lround(std::clamp(coordinate, -kMarkerCoordinateLimit, kMarkerCoordinateLimit)));
}

}  // namespace

// -----------------------------------------------------------------------------------------------

double PlotFrame::pixelX(double x) const {
  const double t = log_x ? std::log10(x) : x;
  const double t_min = log_x ? std::log10(x_min) : x_min, t_max = log_x ? std::log10(x_max) : x_max;
  return left + (t - t_min) / (t_max - t_min) * (right - left);
}

double PlotFrame::pixelY(double y) const {
  const double t = log_y ? std::log10(y) : y;
  const double t_min = log_y ? std::log10(y_min) : y_min, t_max = log_y ? std::log10(y_max) : y_max;
  return bottom - (t - t_min) / (t_max - t_min) * (bottom - top);
}

PlotFrame plotFrame(const std::vector<PlotSeries>& series, const PlotOptions& options) {
  const std::array<std::pair<const char*, int>, 2> sizes = {
      {{"width", options.width}, {"height", options.height}}};
  for (const auto& [name, size] : sizes) {
    if (size < kMinImageSize || size > kMaxImageSize) {
      throw InputError(std::string("plot options: ") + name + " = " + std::to_string(size) +
                       " pixels; expected " + std::to_string(kMinImageSize) + " to " +
                       std::to_string(kMaxImageSize));
    }
  }
  validateSeries(series, options);
  validateReferenceLines(options.h_lines, "h_lines", "y", options.log_y);
  validateReferenceLines(options.v_lines, "v_lines", "x", options.log_x);

  PlotFrame frame;
  frame.width = options.width;
  frame.height = options.height;
  frame.log_x = options.log_x;
  frame.log_y = options.log_y;
  const AxisRange x_range = resolveRange("x", options.log_x, options.x_min, options.x_max,
                                         axisValues(series, options.v_lines, true));
  const AxisRange y_range = resolveRange("y", options.log_y, options.y_min, options.y_max,
                                         axisValues(series, options.h_lines, false));
  frame.x_min = x_range.lo, frame.x_max = x_range.hi;
  frame.y_min = y_range.lo, frame.y_max = y_range.hi;

  frame.top = kTopMargin;
  frame.bottom = options.height - 1 - kBottomMargin;
  const int plot_height = frame.bottom - frame.top;
  frame.y_ticks = options.log_y ? logTicks(frame.y_min, frame.y_max, plot_height, kYLabelSpacing)
                                : linearTicks(frame.y_min, frame.y_max, plot_height);
  // Room for the rotated y label, the widest y tick label and the ticks; at most half the image.
  const int left_margin =
      kYLabelColumn + textHeight() + 10 + widestLabel(frame.y_ticks) + kTickLabelGap;
  frame.left = std::min(left_margin, options.width / 2);
  const int provisional_width = options.width - 1 - kRightMarginMin - frame.left;
  frame.x_ticks = options.log_x
                      ? logTicks(frame.x_min, frame.x_max, provisional_width, kXLabelSpacing)
                      : linearTicks(frame.x_min, frame.x_max, provisional_width);
  // The last x tick label is centred on the right edge: leave room for its right half.
  const int last_label_half = frame.x_ticks.empty() ? 0 : textWidth(frame.x_ticks.back().label) / 2;
  frame.right = options.width - 1 - std::max(kRightMarginMin, last_label_half + 6);
  return frame;
}

Image renderPlot(const std::vector<PlotSeries>& series, const PlotOptions& options) {
  const PlotFrame frame = plotFrame(series, options);
  Image image;
  image.width = options.width;
  image.height = options.height;
  image.rgb.assign(size_t(image.width) * image.height * 3, 255);
  Canvas canvas(image);
  const Box area{frame.left, frame.top, frame.right, frame.bottom};
  const Box inside{frame.left + 1, frame.top + 1, frame.right - 1, frame.bottom - 1};

  // Grid at the major ticks.
  for (const PlotTick& tick : frame.x_ticks) {
    const double x = std::round(frame.pixelX(tick.value));
    if (tick.major) canvas.line(x, frame.top, x, frame.bottom, kGridColor, inside);
  }
  for (const PlotTick& tick : frame.y_ticks) {
    const double y = std::round(frame.pixelY(tick.value));
    if (tick.major) canvas.line(frame.left, y, frame.right, y, kGridColor, inside);
  }

  // Reference lines, dashed, with their labels inside the plot area.
  for (const auto& [value, label] : options.h_lines) {
    const double y = std::round(frame.pixelY(value));
    canvas.line(frame.left, y, frame.right, y, kReferenceColor, inside, 1, 6, 4);
    if (!label.empty() && area.contains(frame.left, roundPixel(y))) {
      canvas.text(frame.right - 4 - textWidth(label), roundPixel(y) - 3 - textHeight(), label,
                  kReferenceColor);
    }
  }
  for (const auto& [value, label] : options.v_lines) {
    const double x = std::round(frame.pixelX(value));
    canvas.line(x, frame.top, x, frame.bottom, kReferenceColor, inside, 1, 6, 4);
    if (!label.empty() && area.contains(roundPixel(x), frame.top)) {
      canvas.text(roundPixel(x) + 4, frame.top + 4, label, kReferenceColor);
    }
  }

  // Series: all lines first, then markers on top, then point labels.
  for (const PlotSeries& s : series) {
    if (!s.lines) continue;
    for (size_t j = 1; j < s.x.size(); ++j) {
      canvas.line(frame.pixelX(s.x[j - 1]), frame.pixelY(s.y[j - 1]), frame.pixelX(s.x[j]),
                  frame.pixelY(s.y[j]), toRgb(s.color), area, 2);
    }
  }
  for (const PlotSeries& s : series) {
    if (!s.markers) continue;
    for (size_t j = 0; j < s.x.size(); ++j) {
      canvas.fillCircle(roundPixel(frame.pixelX(s.x[j])), roundPixel(frame.pixelY(s.y[j])),
                        kMarkerRadius, toRgb(s.color), area);
    }
  }
  for (const PlotSeries& s : series) {
    for (size_t j = 0; j < s.point_labels.size(); ++j) {
      const int x = roundPixel(frame.pixelX(s.x[j])), y = roundPixel(frame.pixelY(s.y[j]));
      if (!area.contains(x, y)) continue;
      canvas.text(x + kMarkerRadius + 3, y - textHeight() / 2, s.point_labels[j], kTextColor);
    }
  }

  // Axes box, ticks (inward, on the bottom and left sides) and tick labels.
  canvas.line(frame.left, frame.top, frame.right, frame.top, kAxisColor, canvas.bounds());
  canvas.line(frame.left, frame.bottom, frame.right, frame.bottom, kAxisColor, canvas.bounds());
  canvas.line(frame.left, frame.top, frame.left, frame.bottom, kAxisColor, canvas.bounds());
  canvas.line(frame.right, frame.top, frame.right, frame.bottom, kAxisColor, canvas.bounds());
  for (const PlotTick& tick : frame.x_ticks) {
    const int x = roundPixel(frame.pixelX(tick.value));
    const int length = tick.major ? kMajorTickLength : kMinorTickLength;
    canvas.line(x, frame.bottom, x, frame.bottom - length, kAxisColor, area);
    if (!tick.label.empty()) {
      canvas.text(x - textWidth(tick.label) / 2, frame.bottom + kTickLabelGap, tick.label,
                  kTextColor);
    }
  }
  for (const PlotTick& tick : frame.y_ticks) {
    const int y = roundPixel(frame.pixelY(tick.value));
    const int length = tick.major ? kMajorTickLength : kMinorTickLength;
    canvas.line(frame.left, y, frame.left + length, y, kAxisColor, area);
    if (!tick.label.empty()) {
      canvas.text(frame.left - kTickLabelGap - textWidth(tick.label), y - textHeight() / 2,
                  tick.label, kTextColor);
    }
  }

  // Axis labels and title.
  const int centre_x = (frame.left + frame.right) / 2, centre_y = (frame.top + frame.bottom) / 2;
  if (!options.x_label.empty()) {
    canvas.text(centre_x - textWidth(options.x_label) / 2,
                frame.bottom + kTickLabelGap + textHeight() + 11, options.x_label, kTextColor);
  }
  if (!options.y_label.empty()) {
    canvas.text(kYLabelColumn, centre_y + textWidth(options.y_label) / 2, options.y_label,
                kTextColor, 1, true);
  }
  if (!options.title.empty()) {
    canvas.text(std::max(4, centre_x - textWidth(options.title, 2) / 2), kTitleRow, options.title,
                kTextColor, 2);
  }

  // Legend: one row (swatch + label) per labelled series, in the corner of the plot area that
  // covers the fewest data points.
  std::vector<const PlotSeries*> entries;
  for (const PlotSeries& s : series)
    if (!s.label.empty()) entries.push_back(&s);
  if (!entries.empty()) {
    constexpr int kPadding = 6, kRowHeight = 12, kSwatchWidth = 14, kInset = 8;
    int widest = 0;
    for (const PlotSeries* s : entries) widest = std::max(widest, textWidth(s->label));
    const int legend_width = 2 * kPadding + kSwatchWidth + 6 + widest;
    const int legend_height =
        2 * kPadding + kRowHeight * int(entries.size()) - (kRowHeight - textHeight());
    const std::array<Box, 4> corners = {{
        {frame.right - kInset - legend_width, frame.top + kInset, frame.right - kInset,
         frame.top + kInset + legend_height},  // top right
        {frame.left + kInset, frame.top + kInset, frame.left + kInset + legend_width,
         frame.top + kInset + legend_height},  // top left
        {frame.right - kInset - legend_width, frame.bottom - kInset - legend_height,
         frame.right - kInset, frame.bottom - kInset},  // bottom right
        {frame.left + kInset, frame.bottom - kInset - legend_height,
         frame.left + kInset + legend_width, frame.bottom - kInset},  // bottom left
    }};
    Box best = corners[0];
    long fewest = -1;
    for (const Box& corner : corners) {
      // Points are counted with their marker radius around the box.
      const Box grown{corner.x0 - kMarkerRadius, corner.y0 - kMarkerRadius,
                      corner.x1 + kMarkerRadius, corner.y1 + kMarkerRadius};
      long covered = 0;
      for (const PlotSeries& s : series) {
        for (size_t j = 0; j < s.x.size(); ++j) {
          covered +=
              grown.contains(roundPixel(frame.pixelX(s.x[j])), roundPixel(frame.pixelY(s.y[j])));
        }
      }
      if (fewest < 0 || covered < fewest) fewest = covered, best = corner;
    }
    canvas.fillRect(best, kWhite);
    canvas.line(best.x0, best.y0, best.x1, best.y0, kLegendBorder, canvas.bounds());
    canvas.line(best.x0, best.y1, best.x1, best.y1, kLegendBorder, canvas.bounds());
    canvas.line(best.x0, best.y0, best.x0, best.y1, kLegendBorder, canvas.bounds());
    canvas.line(best.x1, best.y0, best.x1, best.y1, kLegendBorder, canvas.bounds());
    for (size_t k = 0; k < entries.size(); ++k) {
      const int row = best.y0 + kPadding + kRowHeight * int(k);
      const int swatch_x = best.x0 + kPadding;
      canvas.fillRect({swatch_x, row, swatch_x + kSwatchWidth - 1, row + textHeight() - 1},
                      toRgb(entries[k]->color));
      canvas.text(swatch_x + kSwatchWidth + 6, row, entries[k]->label, kTextColor);
    }
  }
  return image;
}

void drawLabel(Image& image, int x, int y, const std::string& text, const Vec3& color, int scale) {
  if (scale < 1 || scale > 16)
    throw InputError("drawLabel: scale = " + std::to_string(scale) + ", expected 1..16");
  if (image.width <= 0 || image.height <= 0) return;
  Canvas(image).text(x, y, text, toRgb(color), scale);
}

int labelWidth(const std::string& text, int scale) { return textWidth(text, scale); }
int labelHeight(int scale) { return textHeight(scale); }

}  // namespace flsh::render
