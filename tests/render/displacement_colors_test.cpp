// Tests of render::displacementColors, the viridis map of flsh simulate's soft-tissue sheets:
// end colours, the stops, monotone luminance, clamping and input errors.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "flsh/core/error.h"
#include "flsh/render/render.h"
#include "support/test_support.h"

namespace flsh::render {
namespace {

using test::messageOf;
using ::testing::HasSubstr;

Vec3 rgb255(int r, int g, int b) { return Vec3(r, g, b) / 255.0; }

// Relative luminance of an sRGB colour (linearized channels, Rec. 709 weights).
double luminance(const Vec3& srgb) {
  auto linear = [](double c) {
    return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4);
  };
  return 0.2126 * linear(srgb.x()) + 0.7152 * linear(srgb.y()) + 0.0722 * linear(srgb.z());
}

VecX values(std::initializer_list<double> list) {
  VecX v(long(list.size()));
  long i = 0;
  for (double x : list) v[i++] = x;
  return v;
}

TEST(DisplacementColors, ZeroIsDarkPurpleAndTheMaximumIsYellow) {
  const MatX3 c = displacementColors(values({0.0, 0.004}), 0.004);
  ASSERT_EQ(c.rows(), 2);
  EXPECT_TRUE(c.row(0).transpose().isApprox(rgb255(0x44, 0x01, 0x54), 1e-12)) << c.row(0);
  EXPECT_TRUE(c.row(1).transpose().isApprox(rgb255(0xfd, 0xe7, 0x25), 1e-12)) << c.row(1);
  // The documented stops at t = k/6 are hit exactly; halfway between two stops is their mean.
  const MatX3 stops = displacementColors(values({1, 2, 3, 4, 5}), 6.0);
  EXPECT_TRUE(stops.row(0).transpose().isApprox(rgb255(0x44, 0x3a, 0x83), 1e-12));
  EXPECT_TRUE(stops.row(2).transpose().isApprox(rgb255(0x21, 0x90, 0x8c), 1e-12));
  EXPECT_TRUE(stops.row(4).transpose().isApprox(rgb255(0x8f, 0xd7, 0x44), 1e-12));
  const MatX3 half = displacementColors(values({0.5}), 6.0);
  EXPECT_TRUE(half.row(0).transpose().isApprox(
      0.5 * (rgb255(0x44, 0x01, 0x54) + rgb255(0x44, 0x3a, 0x83)), 1e-12));
}

TEST(DisplacementColors, LuminanceIncreasesStrictlyAlongTheMap) {
  const int n = 601;
  const VecX t = VecX::LinSpaced(n, 0.0, 1.0);
  const MatX3 c = displacementColors(t, 1.0);
  ASSERT_EQ(c.rows(), n);
  EXPECT_GE(c.minCoeff(), 0.0);
  EXPECT_LE(c.maxCoeff(), 1.0);
  double previous = -1.0;
  for (int i = 0; i < n; ++i) {
    const double y = luminance(c.row(i).transpose());
    EXPECT_GT(y, previous) << "at t = " << t[i];
    previous = y;
  }
  // A readable range: the top is much brighter than the bottom.
  EXPECT_GT(luminance(c.row(n - 1).transpose()), 20 * luminance(c.row(0).transpose()));
}

TEST(DisplacementColors, ValuesOutsideTheRangeAreClamped) {
  const MatX3 c = displacementColors(values({-1.0, 0.0, 2.0, 5.0, 1e300}), 2.0);
  EXPECT_TRUE(c.row(0).isApprox(c.row(1), 1e-15));  // negative → the 0 colour
  EXPECT_TRUE(c.row(3).isApprox(c.row(2), 1e-15));  // above the maximum → the top colour
  EXPECT_TRUE(c.row(4).isApprox(c.row(2), 1e-15));
  EXPECT_FALSE(c.row(1).isApprox(c.row(2), 1e-3));
  // max_value = 0 (nothing moved): every vertex gets the 0 colour, no division by zero.
  const MatX3 flat = displacementColors(values({0.0, 0.0, 1e-9}), 0.0);
  for (int i = 0; i < 3; ++i)
    EXPECT_TRUE(flat.row(i).transpose().isApprox(rgb255(0x44, 0x01, 0x54), 1e-12));
  EXPECT_EQ(displacementColors(VecX(), 1.0).rows(), 0);
}

TEST(DisplacementColors, NonFiniteInputIsAnErrorNamingIt) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  EXPECT_THAT(messageOf<InputError>([&] {
                displacementColors(values({0.1, nan, 0.2}), 1.0);
              }),
              HasSubstr("displacementColors: argument magnitudes (shape (3,)) has the non-finite "
                        "value nan at index 1"));
  EXPECT_THAT(messageOf<InputError>([&] { displacementColors(values({inf}), 1.0); }),
              HasSubstr("non-finite value inf at index 0"));
  EXPECT_THAT(messageOf<InputError>([&] { displacementColors(values({0.1}), nan); }),
              HasSubstr("displacementColors: argument max_value is nan, expected a finite value"));
  EXPECT_THAT(messageOf<InputError>([&] { displacementColors(values({0.1}), -1.0); }),
              HasSubstr("argument max_value is -1, expected a finite value ≥ 0"));
  EXPECT_THAT(messageOf<InputError>([&] { displacementColors(values({0.1}), inf); }),
              HasSubstr("argument max_value is inf"));
}

}  // namespace
}  // namespace flsh::render
