// The implicit-surface mesher of the synthetic body on shapes with known answers: exact vertex
// counts, closed genus-0 manifold output on the surface, and the genus check.
#include "body/synthetic_mesher.h"

#include <gtest/gtest.h>

#include <cmath>

#include "body/synthetic_mesh_checks.h"
#include "flsh/core/error.h"

namespace flsh::synthetic {
namespace {

ImplicitSurface sphere(double radius) {
  ImplicitSurface s;
  s.value = [radius](const Vec3& p) { return p.norm() - radius; };
  s.relative_edge_length = [](const Vec3&) { return 1.0; };
  s.box_min = Vec3::Constant(-radius - 0.05);
  s.box_max = Vec3::Constant(radius + 0.05);
  return s;
}

TEST(SyntheticMesher, SphereHasExactCountAndIsValid) {
  for (int n : {200, 777}) {
    MesherOptions options;
    options.vertices = n;
    options.grid_spacing = 0.01;
    const TriangleMesh mesh = meshImplicitSurface(sphere(0.3), options);
    ASSERT_EQ(mesh.vertices.rows(), n);
    ASSERT_EQ(mesh.faces.rows(), 2 * n - 4);
    EXPECT_TRUE(test::isClosedGenus0Manifold(mesh.vertices, mesh.faces));
    EXPECT_EQ(test::countSelfIntersections(mesh.vertices, mesh.faces), 0);
    double worst = 0;
    for (int i = 0; i < n; ++i)
      worst = std::max(worst, std::abs(mesh.vertices.row(i).norm() - 0.3));
    EXPECT_LT(worst, 1e-6) << "vertices are projected onto the surface";
    const auto quality = test::meshQuality(mesh.vertices, mesh.faces);
    EXPECT_GT(quality.min_angle_deg, 25.0);
    // Enclosed volume close to the ball's (an inscribed polyhedron is a little smaller).
    const double ball = 4.0 / 3.0 * M_PI * 0.027;
    EXPECT_NEAR(test::enclosedVolume(mesh.vertices, mesh.faces) / ball, 1.0, 0.03);
  }
}

TEST(SyntheticMesher, GradedSizeMakesDenserRegions) {
  ImplicitSurface s = sphere(0.3);
  s.relative_edge_length = [](const Vec3& p) { return p.x() > 0 ? 0.5 : 1.0; };
  MesherOptions options;
  options.vertices = 600;
  const TriangleMesh mesh = meshImplicitSurface(s, options);
  int right = 0;
  for (int i = 0; i < mesh.vertices.rows(); ++i) right += mesh.vertices(i, 0) > 0;
  EXPECT_GT(right, 0.65 * 600) << "half the edge length → about 4× the density";
  EXPECT_TRUE(test::isClosedGenus0Manifold(mesh.vertices, mesh.faces));
}

TEST(SyntheticMesher, RejectsTorusAndTooManyVertices) {
  ImplicitSurface torus;
  torus.value = [](const Vec3& p) {
    const double ring = std::hypot(p.x(), p.z()) - 0.3;
    return std::hypot(ring, p.y()) - 0.1;
  };
  torus.relative_edge_length = [](const Vec3&) { return 1.0; };
  torus.box_min = Vec3(-0.45, -0.15, -0.45);
  torus.box_max = Vec3(0.45, 0.15, 0.45);
  MesherOptions options;
  options.vertices = 300;
  options.grid_spacing = 0.02;
  EXPECT_THROW(meshImplicitSurface(torus, options), Error);

  options.vertices = 100000;  // far more than a 2 cm grid on a small sphere provides
  EXPECT_THROW(meshImplicitSurface(sphere(0.2), options), Error);
}

}  // namespace
}  // namespace flsh::synthetic
