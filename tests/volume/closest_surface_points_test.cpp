// closestSurfacePoints: the closest point of one triangle in each of its regions (inside, edge,
// corner) against the known answer, a body surface against the minimum over every triangle of
// dense samples, determinism with many points (threads), and errors naming the argument.
#include "flsh/volume/closest_surface_points.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>

#include "flsh/core/error.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::messageOf;

MatX3 unitTriangle() {
  MatX3 V(3, 3);
  V << 0, 0, 0, 1, 0, 0, 0, 1, 0;
  return V;
}

TEST(ClosestSurfacePoints, OneTriangleInEveryRegion) {
  const MatX3 V = unitTriangle();
  MatX3i F(1, 3);
  F << 0, 1, 2;
  MatX3 points(4, 3);
  points << 0.2, 0.3, 0.5,  // above the inside
      0.5, -1.0, -0.2,      // beside edge 01
      -1.0, -2.0, 0.0,      // beyond corner 0
      2.0, 2.0, 1.0;        // beyond edge 12
  const ClosestSurfacePoints hits = closestSurfacePoints(V, F, points);
  MatX3 expected(4, 3);
  expected << 0.5, 0.2, 0.3, 0.5, 0.5, 0.0, 1.0, 0.0, 0.0, 0.0, 0.5, 0.5;
  EXPECT_TRUE(hits.barycentric.isApprox(expected, 1e-14)) << hits.barycentric;
  EXPECT_NEAR(hits.distances[0], 0.5, 1e-14);
  EXPECT_NEAR(hits.distances[1], std::sqrt(1.0 + 0.04), 1e-14);
  EXPECT_NEAR(hits.distances[2], std::sqrt(5.0), 1e-14);
  EXPECT_EQ(hits.faces, VecXi::Zero(4));
}

TEST(ClosestSurfacePoints, MatchesDenseSamplesOfEveryTriangleAndIsDeterministic) {
  const auto& scene = test::smallScene(600);
  const MatX3 V = scene.avatar->restVertices();
  const MatX3i F = scene.body->faces;
  const MatX3 points = V + 0.03 * MatX3::Random(V.rows(), 3);
  const ClosestSurfacePoints hits = closestSurfacePoints(V, F, points);
  // Dense barycentric samples of every triangle bound the distance from above, to within the
  // sampling's resolution.
  const int n = 12;
  for (Eigen::Index p = 0; p < points.rows(); p += 37) {
    double sampled = std::numeric_limits<double>::infinity();
    for (Eigen::Index f = 0; f < F.rows(); ++f)
      for (int i = 0; i <= n; ++i)
        for (int j = 0; i + j <= n; ++j) {
          const Vec3 q = (double(i) * V.row(F(f, 0)) + double(j) * V.row(F(f, 1)) +
                          double(n - i - j) * V.row(F(f, 2)))
                             .transpose() /
                         n;
          sampled = std::min(sampled, (q - points.row(p).transpose()).norm());
        }
    const Vec3 w = hits.barycentric.row(p).transpose();
    ASSERT_GE(w.minCoeff(), -1e-12);
    ASSERT_NEAR(w.sum(), 1.0, 1e-12);
    const int f = hits.faces[p];
    const Vec3 q =
        (w[0] * V.row(F(f, 0)) + w[1] * V.row(F(f, 1)) + w[2] * V.row(F(f, 2))).transpose();
    EXPECT_NEAR((q - points.row(p).transpose()).norm(), hits.distances[p], 1e-12);
    EXPECT_LE(hits.distances[p], sampled + 1e-12) << "point " << p;
    EXPECT_GE(hits.distances[p], sampled - 0.01) << "point " << p;  // ~ edge / n
  }
  const ClosestSurfacePoints again = closestSurfacePoints(V, F, points);
  EXPECT_EQ(again.faces, hits.faces);
  EXPECT_EQ(again.barycentric, hits.barycentric);
}

TEST(ClosestSurfacePoints, ErrorsNameTheArgument) {
  const MatX3 V = unitTriangle();
  MatX3i F(1, 3);
  F << 0, 1, 3;
  const MatX3 points = MatX3::Zero(2, 3);
  EXPECT_NE(messageOf<InputError>([&] {
              closestSurfacePoints(V, F, points);
            }).find("faces index outside the 3 vertices"),
            std::string::npos);
  EXPECT_NE(messageOf<InputError>([&] {
              closestSurfacePoints(V, MatX3i(0, 3), points);
            }).find("at least one triangle"),
            std::string::npos);
  MatX3 bad = points;
  bad(1, 2) = std::numeric_limits<double>::quiet_NaN();
  F << 0, 1, 2;
  EXPECT_NE(messageOf<InputError>([&] { closestSurfacePoints(V, F, bad); }).find("points contain"),
            std::string::npos);
}

}  // namespace
}  // namespace flsh
