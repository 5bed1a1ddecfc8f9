// Tests of the sheet's annotations (issue 29, "A picture people can read"): the robust colour
// scale (quantileOf), the colour bar's ticks and strip (colorBarTicks, withColorBar) and text
// labels on images (drawLabel).
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "flsh/core/error.h"
#include "flsh/render/plot.h"
#include "flsh/render/render.h"
#include "support/test_support.h"

namespace flsh::render {
namespace {

using test::messageOf;
using ::testing::ElementsAre;
using ::testing::HasSubstr;

Image blank(int width, int height) {
  Image image;
  image.width = width;
  image.height = height;
  image.rgb.assign(size_t(width) * height * 3, 255);
  return image;
}

bool isWhite(const Image& image, int x, int y) {
  const uint8_t* p = image.pixel(x, y);
  return p[0] == 255 && p[1] == 255 && p[2] == 255;
}

int darkPixels(const Image& image, int x0, int y0, int x1, int y1) {
  int n = 0;
  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x) {
      const uint8_t* p = image.pixel(x, y);
      n += p[0] < 80 && p[1] < 80 && p[2] < 80;
    }
  return n;
}

TEST(QuantileOf, IgnoresASingleOutlierWhereTheMaximumDoesNot) {
  // 1000 values spread over 0..10 mm in two frames and one flopping vertex at 70 mm.
  VecX a = VecX::LinSpaced(500, 0.0, 10.0), b = VecX::LinSpaced(500, 0.0, 10.0);
  b[123] = 70.0;
  const double q = quantileOf({a, b}, 0.99);
  EXPECT_LE(q, 10.0);
  EXPECT_GE(q, 9.5);
  EXPECT_EQ(quantileOf({a, b}, 1.0), 70.0);  // the maximum is the outlier
  // Linear interpolation between order statistics, as numpy.quantile: 0..4 at q = 0.3 → 1.2.
  EXPECT_NEAR(quantileOf({VecX::LinSpaced(5, 4.0, 0.0)}, 0.3), 1.2, 1e-12);
  EXPECT_EQ(quantileOf({VecX::LinSpaced(5, 0.0, 4.0)}, 0.0), 0.0);
  EXPECT_EQ(quantileOf({}, 0.99), 0.0);
  EXPECT_EQ(quantileOf({VecX(), VecX::Constant(1, 3.0)}, 0.5), 3.0);
  VecX bad = a;
  bad[7] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THAT(messageOf<InputError>([&] {
                quantileOf({a, bad}, 0.5);
              }),
              HasSubstr("values[1] has the non-finite value nan at index 7"));
  EXPECT_THAT(messageOf<InputError>([&] { quantileOf({a}, 1.5); }), HasSubstr("q is 1.5"));
}

TEST(ColorBarTicks, AreRoundValuesUpToTheScale) {
  EXPECT_THAT(colorBarTicks(12.3), ElementsAre(0.0, 5.0, 10.0));
  EXPECT_THAT(colorBarTicks(10.0), ElementsAre(0.0, 2.0, 4.0, 6.0, 8.0, 10.0));
  EXPECT_THAT(colorBarTicks(0.7), ElementsAre(0.0, 0.2, 0.4, 0.6000000000000001));
  EXPECT_THAT(colorBarTicks(0.0), ElementsAre(0.0));
  for (double top : {0.013, 1.0, 4.9, 37.0, 64.2, 999.0}) {
    const std::vector<double> ticks = colorBarTicks(top);
    EXPECT_GE(ticks.size(), 2u) << top;
    EXPECT_LE(ticks.size(), 6u) << top;
    EXPECT_LE(ticks.back(), top * (1 + 1e-12)) << top;
  }
  EXPECT_THAT(messageOf<InputError>([] { colorBarTicks(-1.0); }), HasSubstr("max_value is -1"));
  EXPECT_THAT(messageOf<InputError>([] { colorBarTicks(1.0, 1); }), HasSubstr("max_ticks is 1"));
}

TEST(WithColorBar, AppendsAViridisBarWithLabelsBelowTheImage) {
  Image image = blank(640, 100);
  image.pixel(3, 4)[0] = 7;  // the original pixels are kept
  const Image out = withColorBar(image, 12.3, "mm", "soft-tissue |u|");
  ASSERT_EQ(out.width, 640);
  ASSERT_GT(out.height, 100 + 30);
  EXPECT_EQ(out.pixel(3, 4)[0], 7);
  // A row through the bar runs from dark purple (left) to yellow (right), viridis all along.
  const MatX3 ends = displacementColors((VecX(2) << 0.0, 1.0).finished(), 1.0);
  int first = -1, last = -1;
  for (int y = 100; y < out.height && first < 0; ++y) {
    for (int x = 0; x < out.width; ++x) {
      const uint8_t* p = out.pixel(x, y);
      if (std::abs(p[0] - 255 * ends(0, 0)) < 1.5 && std::abs(p[1] - 255 * ends(0, 1)) < 1.5 &&
          std::abs(p[2] - 255 * ends(0, 2)) < 1.5) {
        first = x;
        int k = x;
        while (k + 1 < out.width && !isWhite(out, k + 1, y)) ++k;
        last = k;
        const uint8_t* q = out.pixel(last, y);
        EXPECT_NEAR(q[0], 255 * ends(1, 0), 1.5);
        EXPECT_NEAR(q[1], 255 * ends(1, 1), 1.5);
        EXPECT_NEAR(q[2], 255 * ends(1, 2), 1.5);
        break;
      }
    }
  }
  ASSERT_GE(first, 0) << "no colour bar";
  EXPECT_GE(last - first, 200);
  // Labels (dark text) under the bar and a caption above it.
  EXPECT_GT(darkPixels(out, 0, 100, out.width, out.height), 100);
  EXPECT_THAT(messageOf<InputError>([&] { withColorBar(blank(20, 10), 1.0, "mm", ""); }),
              HasSubstr("at least 64 wide"));
  EXPECT_THAT(messageOf<InputError>([&] { withColorBar(image, -2.0, "mm", ""); }),
              HasSubstr("max_value is -2"));
}

TEST(DrawLabel, DrawsTextClippedToTheImage) {
  Image image = blank(120, 40);
  drawLabel(image, 4, 4, "t = 0.50 s", Vec3::Zero(), 2);
  const int inside = darkPixels(image, 0, 0, 120, 40);
  EXPECT_GT(inside, 60);
  EXPECT_EQ(darkPixels(image, 0, 4 + labelHeight(2) + 4, 120, 40), 0);  // one line, no descender
  EXPECT_EQ(labelWidth("t = 0.50 s", 2), 2 * (10 * 6 - 1));
  // Partly outside: clipped, no crash; nothing drawn when entirely outside.
  drawLabel(image, 100, 35, "clipped", Vec3::Zero());
  Image outside = blank(20, 20);
  drawLabel(outside, 50, 50, "away", Vec3::Zero());
  EXPECT_EQ(darkPixels(outside, 0, 0, 20, 20), 0);
  EXPECT_THAT(messageOf<InputError>([&] { drawLabel(image, 0, 0, "x", Vec3::Zero(), 0); }),
              HasSubstr("scale = 0"));
}

}  // namespace
}  // namespace flsh::render
