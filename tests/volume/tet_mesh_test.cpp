// tetrahedralizeSurface and the tet-mesh helpers: invariants on the synthetic body (surface nodes
// and faces kept exactly), volume conservation, quality, the resolution option, determinism,
// flip recovery on a jittered sphere, a thin slab, and clear errors for bad surfaces and meshes;
// quality improvement (slivers of the raw body mesh removed, a 2–3 flip, an interior-node move,
// shape changes X̄(β) that no longer invert or flatten tets).
#include "flsh/volume/tet_mesh.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <utility>

#include "flsh/core/error.h"
#include "flsh/volume/volume_fields.h"
#include "support/test_support.h"
#include "volume/volume_test_meshes.h"

namespace flsh {
namespace {

using test::icosphere;
using test::messageOf;
using test::solidIntegrals;
using test::TriangleMesh;

struct Meshed {
  TriangleMesh surface;
  TetMesh mesh;
  TetMeshTimings timings;
};

Meshed meshOf(const TriangleMesh& surface, const TetMeshOptions& options = {}) {
  Meshed m;
  m.surface = surface;
  m.mesh = tetrahedralizeSurface(surface.V, surface.F, options, &m.timings);
  return m;
}

TriangleMesh bodySurface(int vertices) {
  if (vertices == 1000) {
    const auto body = test::smallSyntheticBody();
    return {body->v_template, body->faces};
  }
  const BodyModel body = makeSyntheticBody({vertices, 1.70});
  return {body.v_template, body.faces};
}

// The 1000-vertex synthetic body's mesh at resolution 1, built once per binary.
const Meshed& smallBodyMesh() {
  static const Meshed meshed = meshOf(bodySurface(1000));
  return meshed;
}

// The same mesh without the quality improvement: the Delaunay tets of the surface and Mesh_3
// points after boundary recovery, with their slivers.
const Meshed& smallBodyRawMesh() {
  static const Meshed meshed = [] {
    TetMeshOptions options;
    options.improve_quality = false;
    return meshOf(bodySurface(1000), options);
  }();
  return meshed;
}

// Per tet, its dihedral angle farthest from 90° folded onto [0°, 90°], i.e. min(θ, 180° − θ) over
// its six edges, in degrees (small for both slivers' flat and obtuse angles). From the face
// normals, independently of the library's sine formula.
VecX worstFoldedAngles(const TetMesh& mesh) {
  static constexpr int kEdges[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};
  VecX out(mesh.numTets());
  for (int t = 0; t < mesh.numTets(); ++t) {
    Vec3 x[4];
    for (int k = 0; k < 4; ++k) x[k] = mesh.nodes.row(mesh.tets(t, k)).transpose();
    // Outward face normals opposite each vertex.
    const Vec3 n[4] = {(x[2] - x[1]).cross(x[3] - x[1]), (x[3] - x[0]).cross(x[2] - x[0]),
                       (x[1] - x[0]).cross(x[3] - x[0]), (x[2] - x[0]).cross(x[1] - x[0])};
    double worst = 90;
    for (const auto& e : kEdges) {
      int o[2], m = 0;
      for (int v = 0; v < 4; ++v)
        if (v != e[0] && v != e[1]) o[m++] = v;
      const double c = -n[o[0]].dot(n[o[1]]) / (n[o[0]].norm() * n[o[1]].norm());
      const double angle = std::acos(std::clamp(c, -1.0, 1.0)) * 180 / M_PI;
      worst = std::min({worst, angle, 180 - angle});
    }
    out[t] = worst;
  }
  return out;
}

// An icosphere whose vertices slide along the sphere by up to `jitter` × the edge length: the
// surface stays closed and convex-ish but is far from the Delaunay triangulation of its vertices,
// so many surface faces are missing from the Delaunay tetrahedralization.
TriangleMesh jitteredSphere(int levels, double radius, double jitter, unsigned seed) {
  TriangleMesh m = icosphere(levels, radius, Vec3::Zero());
  std::mt19937 random(seed);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  const double edge = radius * 1.1 / (1 << levels);
  for (int i = 0; i < m.V.rows(); ++i) {
    const Vec3 p = m.V.row(i).transpose();
    const Vec3 normal = p.normalized();
    Vec3 step(uniform(random), uniform(random), uniform(random));
    step -= step.dot(normal) * normal;
    m.V.row(i) = (radius * (p + jitter * edge * step).normalized()).transpose();
  }
  return m;
}

std::array<int, 3> canonical(int a, int b, int c) {
  if (b < a && b < c) return {b, c, a};
  if (c < a && c < b) return {c, a, b};
  return {a, b, c};
}

// Everything a tet mesh of `surface` must satisfy, checked independently of validateTetMesh too.
void expectMeshesSurface(const Meshed& m) {
  const TriangleMesh& s = m.surface;
  const TetMesh& mesh = m.mesh;
  EXPECT_NO_THROW(validateTetMesh(mesh, s.F));
  ASSERT_EQ(mesh.num_surface_nodes, s.V.rows());
  ASSERT_GE(mesh.numNodes(), s.V.rows());
  EXPECT_EQ(std::memcmp(mesh.nodes.data(), s.V.data(), sizeof(double) * size_t(s.V.size())), 0)
      << "surface nodes must be the input vertices, bitwise";
  // Boundary faces == F as oriented triangles.
  std::vector<std::array<int, 3>> expected;
  for (int f = 0; f < s.F.rows(); ++f)
    expected.push_back(canonical(s.F(f, 0), s.F(f, 1), s.F(f, 2)));
  std::sort(expected.begin(), expected.end());
  const MatX3i boundary = boundaryFaces(mesh.tets);
  ASSERT_EQ(boundary.rows(), s.F.rows());
  for (int f = 0; f < boundary.rows(); ++f)
    ASSERT_EQ((std::array<int, 3>{boundary(f, 0), boundary(f, 1), boundary(f, 2)}),
              expected[size_t(f)])
        << "boundary face " << f;
  // Positive volumes summing to the enclosed volume (divergence theorem).
  const VecX volumes = tetVolumes(mesh);
  EXPECT_GT(volumes.minCoeff(), 0.0);
  const double enclosed = solidIntegrals(s).volume;
  EXPECT_NEAR(volumes.sum(), enclosed, 1e-10 * enclosed);
}

TEST(TetMesh, BodyMeshKeepsTheSurfaceExactly) {
  const Meshed& m = smallBodyMesh();
  expectMeshesSurface(m);
  // Interior nodes exist and are strictly inside the body.
  ASSERT_GT(m.mesh.numNodes(), m.mesh.num_surface_nodes);
  for (int i = m.mesh.num_surface_nodes; i < m.mesh.numNodes(); i += 17)
    EXPECT_NEAR(test::windingNumber(m.surface.V, m.surface.F, m.mesh.nodes.row(i).transpose()), 1.0,
                1e-6)
        << "node " << i;
  std::cout << "1000-vertex body: " << m.mesh.numNodes() << " nodes, " << m.mesh.numTets()
            << " tets, " << m.timings.recovered_faces << " recovered faces, " << m.timings.total
            << " s\n";
}

TEST(TetMesh, QualityIsFiniteAndReported) {
  const TetMeshQuality q = tetMeshQuality(smallBodyMesh().mesh);
  std::cout << "dihedral [" << q.min_dihedral_deg << ", " << q.max_dihedral_deg
            << "] deg, radius-edge max " << q.max_radius_edge_ratio << " mean "
            << q.mean_radius_edge_ratio << ", min volume " << q.min_volume << " m³\n";
  EXPECT_GT(q.min_dihedral_deg, 0.0);
  EXPECT_LT(q.min_dihedral_deg, 70.53);  // the regular tet's angle bounds the minimum from above
  EXPECT_GT(q.max_dihedral_deg, 70.52);
  EXPECT_LT(q.max_dihedral_deg, 180.0);
  EXPECT_GE(q.mean_radius_edge_ratio, std::sqrt(6.0) / 4 - 1e-12);  // regular tet: √6/4
  EXPECT_LT(q.mean_radius_edge_ratio, 1.5);
  EXPECT_GE(q.max_radius_edge_ratio, q.mean_radius_edge_ratio);
  EXPECT_TRUE(std::isfinite(q.max_radius_edge_ratio));
  EXPECT_GT(q.min_volume, 0.0);
}

TEST(TetMesh, RegularTetQualityAndVolume) {
  TetMesh mesh;
  mesh.nodes.resize(4, 3);
  mesh.nodes << 1, 1, 1, 1, -1, -1, -1, 1, -1, -1, -1, 1;
  mesh.tets.resize(1, 4);
  mesh.tets << 0, 2, 1, 3;  // positively oriented
  mesh.num_surface_nodes = 4;
  const double edge = std::sqrt(8.0);
  const VecX volumes = tetVolumes(mesh);
  ASSERT_EQ(volumes.size(), 1);
  EXPECT_NEAR(volumes[0], edge * edge * edge / (6 * std::sqrt(2.0)), 1e-12);
  const TetMeshQuality q = tetMeshQuality(mesh);
  const double regular = std::acos(1.0 / 3.0) * 180 / M_PI;  // 70.5288°
  EXPECT_NEAR(q.min_dihedral_deg, regular, 1e-9);
  EXPECT_NEAR(q.max_dihedral_deg, regular, 1e-9);
  EXPECT_NEAR(q.max_radius_edge_ratio, std::sqrt(6.0) / 4, 1e-12);
  EXPECT_NEAR(q.min_volume, volumes[0], 1e-15);
  // Its four faces, outward, are the boundary; validate accepts exactly them.
  const MatX3i F = boundaryFaces(mesh.tets);
  ASSERT_EQ(F.rows(), 4);
  for (int f = 0; f < 4; ++f) {
    const Vec3 a = mesh.nodes.row(F(f, 0)), b = mesh.nodes.row(F(f, 1)),
               c = mesh.nodes.row(F(f, 2));
    EXPECT_GT((b - a).cross(c - a).dot((a + b + c) / 3), 0.0) << "face " << f << " points inward";
  }
  EXPECT_NO_THROW(validateTetMesh(mesh, F));
}

TEST(TetMesh, InteriorNodeCountFollowsTheResolution) {
  const TriangleMesh surface = bodySurface(600);
  int interior[3];
  const double resolutions[3] = {0.5, 1.0, 2.0};
  for (int r = 0; r < 3; ++r) {
    const Meshed m = meshOf(surface, {resolutions[r], 1});
    expectMeshesSurface(m);
    interior[r] = m.mesh.numNodes() - m.mesh.num_surface_nodes;
  }
  const double target = 0.45 * 600;
  EXPECT_GT(interior[1], 0.6 * target);
  EXPECT_LT(interior[1], 1.6 * target);
  EXPECT_GT(double(interior[2]) / interior[1], 1.4);
  EXPECT_LT(double(interior[2]) / interior[1], 2.8);
  EXPECT_GT(double(interior[1]) / interior[0], 1.4);
  EXPECT_LT(double(interior[1]) / interior[0], 2.8);
}

TEST(TetMesh, SameInputGivesTheSameBytes) {
  const TriangleMesh surface = bodySurface(1000);
  const TetMesh again = tetrahedralizeSurface(surface.V, surface.F);
  const TetMesh& first = smallBodyMesh().mesh;
  ASSERT_EQ(again.nodes.rows(), first.nodes.rows());
  ASSERT_EQ(again.tets.rows(), first.tets.rows());
  EXPECT_EQ(std::memcmp(again.nodes.data(), first.nodes.data(),
                        sizeof(double) * size_t(first.nodes.size())),
            0);
  EXPECT_EQ(
      std::memcmp(again.tets.data(), first.tets.data(), sizeof(int) * size_t(first.tets.size())),
      0);
}

TEST(TetMesh, JitteredSphereIsRecoveredByFlips) {
  const Meshed m = meshOf(jitteredSphere(3, 0.1, 0.35, 7));
  EXPECT_GT(m.timings.recovered_faces, 20) << "the jittered sphere is meant to need recovery";
  expectMeshesSurface(m);
  EXPECT_GT(m.mesh.numNodes(), m.mesh.num_surface_nodes);
}

TEST(TetMesh, ThinSlabWithoutRoomForInteriorNodes) {
  TriangleMesh slab = icosphere(3, 0.1, Vec3::Zero());
  slab.V.col(2) *= 0.02;  // 4 mm thick, 20 cm wide
  const Meshed m = meshOf(slab);
  expectMeshesSurface(m);
  EXPECT_GT(m.timings.recovered_faces, 0);
}

TEST(TetMesh, BoundaryFacesOfTwoTetsAndNonManifoldTets) {
  // Two positive tets sharing face (1, 2, 3).
  MatX4i tets(2, 4);
  tets << 0, 1, 2, 3, 4, 1, 3, 2;
  const MatX3i boundary = boundaryFaces(tets);
  MatX3i expected(6, 3);
  expected << 0, 1, 3, 0, 2, 1, 0, 3, 2, 1, 2, 4, 1, 4, 3, 2, 3, 4;
  EXPECT_EQ(boundary, expected);
  // The second tet inverted: the shared face has the same orientation twice.
  tets.row(1) << 4, 1, 2, 3;
  EXPECT_NE(messageOf<Error>([&] { boundaryFaces(tets); }).find("same orientation"),
            std::string::npos);
  // Three tets on one face.
  MatX4i three(3, 4);
  three << 0, 1, 2, 3, 4, 1, 3, 2, 5, 1, 3, 2;
  EXPECT_NE(messageOf<Error>([&] { boundaryFaces(three); }).find("belongs to 3 tets"),
            std::string::npos);
}

TEST(TetMesh, ValidateReportsTheFirstViolation) {
  const Meshed& m = smallBodyMesh();
  {
    TetMesh bad = m.mesh;
    std::swap(bad.tets(5, 0), bad.tets(5, 1));
    EXPECT_NE(
        messageOf<Error>([&] { validateTetMesh(bad, m.surface.F); }).find("inverted or degenerate"),
        std::string::npos);
  }
  {
    TetMesh bad = m.mesh;
    bad.nodes.conservativeResize(bad.nodes.rows() + 1, 3);
    bad.nodes.bottomRows(1).setZero();
    EXPECT_NE(messageOf<Error>([&] { validateTetMesh(bad, m.surface.F); }).find("used by no tet"),
              std::string::npos);
  }
  {
    TetMesh bad = m.mesh;
    bad.tets.conservativeResize(bad.tets.rows() - 1, 4);  // opens a hole in the mesh
    const std::string message = messageOf<Error>([&] { validateTetMesh(bad, m.surface.F); });
    EXPECT_TRUE(message.find("is not a face of F") != std::string::npos ||
                message.find("used by no tet") != std::string::npos)
        << message;
  }
  {
    MatX3i flipped = m.surface.F;
    flipped.row(3) = m.surface.F.row(3).reverse();
    const std::string message = messageOf<Error>([&] { validateTetMesh(m.mesh, flipped); });
    EXPECT_TRUE(message.find("as an outward triangle") != std::string::npos ||
                message.find("is not a face of F") != std::string::npos)
        << message;
  }
  {
    TetMesh bad = m.mesh;
    bad.tets(0, 2) = bad.numNodes();
    EXPECT_NE(messageOf<Error>([&] { validateTetMesh(bad, m.surface.F); }).find("outside [0, "),
              std::string::npos);
  }
}

// The sphere and its mirror image across the tangent plane at vertex 0, sharing that vertex.
TriangleMesh spheresTouchingAtOneVertex() {
  const TriangleMesh a = icosphere(1, 0.1, Vec3::Zero());
  const Vec3 p = a.V.row(0).transpose(), d = p.normalized();
  const int n = int(a.V.rows());
  TriangleMesh m;
  m.V.resize(2 * n - 1, 3);
  m.V.topRows(n) = a.V;
  std::vector<int> index(static_cast<size_t>(n));
  index[0] = 0;
  for (int i = 1; i < n; ++i) {
    const Vec3 x = a.V.row(i).transpose();
    m.V.row(n + i - 1) = (x - 2 * (x - p).dot(d) * d).transpose();
    index[size_t(i)] = n + i - 1;
  }
  m.F.resize(2 * a.F.rows(), 3);
  m.F.topRows(a.F.rows()) = a.F;
  for (int f = 0; f < a.F.rows(); ++f)  // a mirror image: reverse the faces to stay outward
    m.F.row(a.F.rows() + f) << index[size_t(a.F(f, 0))], index[size_t(a.F(f, 2))],
        index[size_t(a.F(f, 1))];
  return m;
}

TEST(TetMesh, RejectsBadSurfacesWithClearMessages) {
  const TriangleMesh sphere = icosphere(2, 0.1, Vec3::Zero());
  const auto messageFor = [](const MatX3& V, const MatX3i& F, const TetMeshOptions& o = {}) {
    return messageOf<InputError>([&] { tetrahedralizeSurface(V, F, o); });
  };
  // Open: one face removed.
  EXPECT_NE(messageFor(sphere.V, sphere.F.topRows(sphere.F.rows() - 1)).find("closed surface"),
            std::string::npos);
  // Inverted orientation.
  MatX3i inverted = sphere.F;
  inverted.col(1).swap(inverted.col(2));
  EXPECT_NE(messageFor(sphere.V, inverted).find("orientation inverted?"), std::string::npos);
  // Non-manifold vertex.
  const TriangleMesh touching = spheresTouchingAtOneVertex();
  EXPECT_NE(messageFor(touching.V, touching.F).find("vertex 0 is non-manifold"), std::string::npos);
  // Non-manifold edge: a face repeated.
  MatX3i repeated(sphere.F.rows() + 1, 3);
  repeated << sphere.F, sphere.F.row(0);
  EXPECT_NE(messageFor(sphere.V, repeated).find("same direction"), std::string::npos);
  // Self-intersecting: two overlapping spheres, each closed and outward.
  const TriangleMesh other = icosphere(2, 0.1, Vec3(0.05, 0.0, 0.0));
  MatX3 V2(2 * sphere.V.rows(), 3);
  V2 << sphere.V, other.V;
  MatX3i F2(2 * sphere.F.rows(), 3);
  F2 << sphere.F, (other.F.array() + int(sphere.V.rows())).matrix();
  EXPECT_NE(messageFor(V2, F2).find("intersects itself"), std::string::npos);
  // Unreferenced vertex, NaN, out-of-range index, bad resolution.
  MatX3 extra(sphere.V.rows() + 1, 3);
  extra << sphere.V, Eigen::RowVector3d(1, 1, 1);
  EXPECT_NE(messageFor(extra, sphere.F).find("used by no face"), std::string::npos);
  MatX3 nan = sphere.V;
  nan(3, 1) = std::nan("");
  EXPECT_NE(messageFor(nan, sphere.F).find("NaN"), std::string::npos);
  MatX3i out_of_range = sphere.F;
  out_of_range(2, 1) = int(sphere.V.rows());
  EXPECT_NE(messageFor(sphere.V, out_of_range).find("out of range"), std::string::npos);
  EXPECT_NE(messageFor(sphere.V, sphere.F, {0.0, 1}).find("resolution"), std::string::npos);
}

TEST(TetMeshImprovement, RemovesTheSliversOfTheBodyMeshAndKeepsTheSurface) {
  const Meshed& raw = smallBodyRawMesh();
  Meshed improved = raw;
  const TetMeshImprovement stats = improveTetMeshQuality(improved.mesh);
  expectMeshesSurface(improved);
  ASSERT_EQ(improved.mesh.numNodes(), raw.mesh.numNodes());
  for (int i = improved.mesh.num_surface_nodes; i < improved.mesh.numNodes(); i += 7)
    EXPECT_NEAR(test::windingNumber(improved.surface.V, improved.surface.F,
                                    improved.mesh.nodes.row(i).transpose()),
                1.0, 1e-6)
        << "node " << i;

  const VecX before = worstFoldedAngles(raw.mesh), after = worstFoldedAngles(improved.mesh);
  const auto countUnder = [](const VecX& angles, double limit) {
    return int((angles.array() < limit).count());
  };
  std::cout << "1000-vertex body: worst folded dihedral " << before.minCoeff() << "° -> "
            << after.minCoeff() << "°, tets under 10° " << countUnder(before, 10) << " -> "
            << countUnder(after, 10) << ", " << stats.edge_removals << " edge removals, "
            << stats.face_flips << " face flips, " << stats.node_moves << " node moves\n";
  ASSERT_LT(before.minCoeff(), 5.0) << "the raw mesh is meant to have slivers";
  // No tet is worse than the worst before, by a wide margin.
  EXPECT_GT(after.minCoeff(), before.minCoeff() + 5.0);
  EXPECT_LT(countUnder(after, 10), countUnder(before, 10));
  const TetMeshQuality q_before = tetMeshQuality(raw.mesh), q_after = tetMeshQuality(improved.mesh);
  EXPECT_GT(q_after.min_dihedral_deg, q_before.min_dihedral_deg);
  EXPECT_LT(q_after.max_dihedral_deg, q_before.max_dihedral_deg);
  EXPECT_LE(q_after.max_radius_edge_ratio, std::max(2.5, q_before.max_radius_edge_ratio));
  EXPECT_GT(stats.edge_removals + stats.face_flips, 0);
  EXPECT_GT(stats.min_sine_after, stats.min_sine_before);
  EXPECT_NEAR(stats.min_sine_after, std::sin(after.minCoeff() * M_PI / 180), 1e-9);
}

TEST(TetMeshImprovement, IsDeterministicAndIsWhatTetrahedralizeSurfaceReturns) {
  TetMesh first = smallBodyRawMesh().mesh, second = smallBodyRawMesh().mesh;
  improveTetMeshQuality(first);
  improveTetMeshQuality(second);
  ASSERT_EQ(first.tets.rows(), second.tets.rows());
  EXPECT_EQ(std::memcmp(first.nodes.data(), second.nodes.data(),
                        sizeof(double) * size_t(first.nodes.size())),
            0);
  EXPECT_EQ(
      std::memcmp(first.tets.data(), second.tets.data(), sizeof(int) * size_t(first.tets.size())),
      0);
  const TetMesh& pipeline = smallBodyMesh().mesh;  // improve_quality is on by default
  ASSERT_EQ(pipeline.tets.rows(), first.tets.rows());
  EXPECT_EQ(std::memcmp(pipeline.nodes.data(), first.nodes.data(),
                        sizeof(double) * size_t(first.nodes.size())),
            0);
  EXPECT_EQ(
      std::memcmp(pipeline.tets.data(), first.tets.data(), sizeof(int) * size_t(first.tets.size())),
      0);
  // A second run finds nothing to make worse: its worst tet is at least as good.
  TetMesh again = first;
  const TetMeshImprovement stats = improveTetMeshQuality(again);
  EXPECT_GE(stats.min_sine_after, stats.min_sine_before);
  EXPECT_GE(worstFoldedAngles(again).minCoeff(), worstFoldedAngles(first).minCoeff() - 1e-9);
}

TEST(TetMeshImprovement, FlipsTwoFlatTetsIntoThree) {
  // Two flat tets on an equilateral triangle, apexes just above and below its centre: the 2–3
  // flip to three tets around the apexes' edge doubles the worst angle. No node can move (all
  // are surface nodes), and the five outer faces stay.
  TetMesh mesh;
  mesh.nodes.resize(5, 3);
  mesh.nodes << 1, 0, 0, -0.5, std::sqrt(0.75), 0, -0.5, -std::sqrt(0.75), 0, 0, 0, 0.05, 0, 0,
      -0.05;
  mesh.num_surface_nodes = 5;
  mesh.tets.resize(2, 4);
  mesh.tets << 0, 1, 2, 3, 0, 2, 1, 4;
  const MatX3i F = boundaryFaces(mesh.tets);
  const double before = worstFoldedAngles(mesh).minCoeff();
  const TetMeshImprovement stats = improveTetMeshQuality(mesh);
  EXPECT_EQ(stats.face_flips, 1);
  EXPECT_EQ(stats.node_moves, 0);
  ASSERT_EQ(mesh.numTets(), 3);
  EXPECT_NO_THROW(validateTetMesh(mesh, F));
  EXPECT_GT(worstFoldedAngles(mesh).minCoeff(), 1.9 * before);
  for (int t = 0; t < 3; ++t) {  // every new tet has the edge between the apexes (nodes 3, 4)
    const auto row = mesh.tets.row(t);
    EXPECT_TRUE((row.array() == 3).any() && (row.array() == 4).any()) << "tet " << t;
  }
}

TEST(TetMeshImprovement, MovesAnInteriorNodeAwayFromTheSurface) {
  // A unit cube coned from one interior node 1 cm under its top face: the six top-face-adjacent
  // tets are flat. Only that node may move; the corners and the twelve faces stay.
  const TriangleMesh box = test::boxMesh(Vec3(1, 1, 1), Vec3::Zero());
  TetMesh mesh;
  mesh.num_surface_nodes = 8;
  mesh.nodes.resize(9, 3);
  mesh.nodes.topRows(8) = box.V;
  mesh.nodes.row(8) << 0.1, -0.05, 0.49;
  mesh.tets.resize(12, 4);
  for (int f = 0; f < 12; ++f)  // an outward face seen from the inside, then the apex: positive
    mesh.tets.row(f) << box.F(f, 0), box.F(f, 2), box.F(f, 1), 8;
  ASSERT_GT(tetVolumes(mesh).minCoeff(), 0.0);
  const MatX3 corners = mesh.nodes.topRows(8);
  const double before = worstFoldedAngles(mesh).minCoeff();
  const TetMeshImprovement stats = improveTetMeshQuality(mesh);
  EXPECT_GT(stats.node_moves, 0);
  EXPECT_NO_THROW(validateTetMesh(mesh, box.F));
  EXPECT_EQ(mesh.nodes.topRows(8), corners);
  EXPECT_LT(mesh.nodes(8, 2), 0.3) << "the node should move well away from the top face";
  EXPECT_GT(worstFoldedAngles(mesh).minCoeff(), before + 10);
}

TEST(TetMeshImprovement, ShapedBodyNodesNoLongerFormSlivers) {
  // X̄(β) = X̄₀ + S β moves the interior nodes harmonically; slivers of the raw mesh flatten or
  // invert first. After improvement, every β_k = ±3 keeps all tets positive and well away from
  // flat.
  const auto body = test::smallSyntheticBody();
  const auto worstUnderShapes = [&](const TetMesh& mesh) {
    const HarmonicExtension harmonic(mesh);
    const InteriorFields fields = extendBodyFields(mesh, *body, harmonic);
    double worst_angle = 90, worst_volume = std::numeric_limits<double>::infinity();
    for (int k = 0; k < body->numBetas(); ++k)
      for (const double value : {-3.0, 3.0}) {
        VecX beta = VecX::Zero(body->numBetas());
        beta[k] = value;
        TetMesh shaped = mesh;
        shaped.nodes = shapedNodes(mesh, fields, beta);
        worst_volume = std::min(worst_volume, tetVolumes(shaped).minCoeff());
        worst_angle = std::min(worst_angle, worstFoldedAngles(shaped).minCoeff());
      }
    return std::make_pair(worst_angle, worst_volume);
  };
  const auto raw = worstUnderShapes(smallBodyRawMesh().mesh);
  const auto improved = worstUnderShapes(smallBodyMesh().mesh);
  std::cout << "worst folded dihedral over beta_k = ±3: " << raw.first << "° raw, "
            << improved.first << "° improved\n";
  EXPECT_GT(improved.second, 0.0);
  EXPECT_GT(improved.first, 5.0);
  EXPECT_GT(improved.first, raw.first + 5.0);
}

TEST(TetMeshImprovement, RejectsInvalidMeshes) {
  TetMesh mesh = smallBodyRawMesh().mesh;
  std::swap(mesh.tets(3, 0), mesh.tets(3, 1));
  EXPECT_NE(messageOf<InputError>([&] { improveTetMeshQuality(mesh); }).find("tet 3 has volume"),
            std::string::npos);
  mesh = smallBodyRawMesh().mesh;
  mesh.tets(2, 3) = -1;
  EXPECT_NE(messageOf<InputError>([&] { improveTetMeshQuality(mesh); }).find("outside [0, "),
            std::string::npos);
  mesh = smallBodyRawMesh().mesh;
  mesh.tets(2, 3) = mesh.tets(2, 0);
  EXPECT_NE(messageOf<InputError>([&] { improveTetMeshQuality(mesh); }).find("repeats node"),
            std::string::npos);
}

}  // namespace
}  // namespace flsh
