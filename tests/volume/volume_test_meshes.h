// Shared inputs of the volume tests: the small synthetic body (generated once per binary),
// closed analytic meshes (box, icosphere), their exact solid integrals and an inside test, and
// structured tet meshes of boxes (no CGAL) with the boundary nodes first, as TetMesh requires.
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <memory>
#include <utility>
#include <vector>

#include "flsh/body/body_model.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/types.h"
#include "flsh/volume/tet_mesh.h"

namespace flsh::test {

/// The 1000-vertex synthetic body, 1.70 m (generated once, ~0.5 s).
inline std::shared_ptr<const BodyModel> smallSyntheticBody() {
  static const auto body = std::make_shared<const BodyModel>(makeSyntheticBody({1000, 1.70}));
  return body;
}

struct TriangleMesh {
  MatX3 V;   // #V × 3, m
  MatX3i F;  // #F × 3, counter-clockwise seen from outside
};

/// Axis-aligned box of the given edge lengths centred at `centre` (8 vertices, 12 triangles).
inline TriangleMesh boxMesh(const Vec3& size, const Vec3& centre) {
  TriangleMesh m;
  m.V.resize(8, 3);
  for (int i = 0; i < 8; ++i)
    m.V.row(i) =
        (centre + 0.5 * Vec3((i & 1) ? size.x() : -size.x(), (i & 2) ? size.y() : -size.y(),
                             (i & 4) ? size.z() : -size.z()))
            .transpose();
  // Quads (outward, counter-clockwise) split into two triangles each.
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  m.F.resize(12, 3);
  for (int q = 0; q < 6; ++q) {
    m.F.row(2 * q) << quads[q][0], quads[q][1], quads[q][2];
    m.F.row(2 * q + 1) << quads[q][0], quads[q][2], quads[q][3];
  }
  return m;
}

/// Icosahedron subdivided `levels` times, vertices on the sphere of `radius` about `centre`.
inline TriangleMesh icosphere(int levels, double radius, const Vec3& centre) {
  const double t = (1 + std::sqrt(5.0)) / 2;
  std::vector<Vec3> points = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0},
                              {0, -1, t}, {0, 1, t}, {0, -1, -t}, {0, 1, -t},
                              {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  for (Vec3& p : points) p.normalize();
  std::vector<std::array<int, 3>> faces = {
      {0, 11, 5},  {0, 5, 1},  {0, 1, 7},  {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
      {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
      {3, 8, 9},   {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
  for (int level = 0; level < levels; ++level) {
    std::map<std::pair<int, int>, int> midpoint;
    auto middle = [&](int a, int b) {
      const auto key = std::minmax(a, b);
      auto found = midpoint.find(key);
      if (found != midpoint.end()) return found->second;
      points.push_back((points[a] + points[b]).normalized());
      return midpoint[key] = int(points.size()) - 1;
    };
    std::vector<std::array<int, 3>> finer;
    for (const auto& f : faces) {
      const int ab = middle(f[0], f[1]), bc = middle(f[1], f[2]), ca = middle(f[2], f[0]);
      finer.push_back({f[0], ab, ca});
      finer.push_back({f[1], bc, ab});
      finer.push_back({f[2], ca, bc});
      finer.push_back({ab, bc, ca});
    }
    faces = std::move(finer);
  }
  TriangleMesh m;
  m.V.resize(points.size(), 3);
  for (size_t i = 0; i < points.size(); ++i) m.V.row(i) = (centre + radius * points[i]).transpose();
  m.F.resize(faces.size(), 3);
  for (size_t f = 0; f < faces.size(); ++f) m.F.row(f) << faces[f][0], faces[f][1], faces[f][2];
  return m;
}

/// Exact solid integrals of a closed polyhedron: volume, ∫X dV and ∫X Xᵀ dV (signed
/// tetrahedra from the origin; ∫_T X Xᵀ = det/120 (Σ v vᵀ + s sᵀ), s = Σ v).
struct SolidIntegrals {
  double volume = 0;
  Vec3 first = Vec3::Zero();
  Mat3 second = Mat3::Zero();
};
inline SolidIntegrals solidIntegrals(const TriangleMesh& m) {
  SolidIntegrals out;
  for (int f = 0; f < m.F.rows(); ++f) {
    const Vec3 a = m.V.row(m.F(f, 0)), b = m.V.row(m.F(f, 1)), c = m.V.row(m.F(f, 2));
    const double det = a.dot(b.cross(c));
    const Vec3 s = a + b + c;
    out.volume += det / 6;
    out.first += det / 24 * s;
    out.second +=
        det / 120 * (a * a.transpose() + b * b.transpose() + c * c.transpose() + s * s.transpose());
  }
  return out;
}

/// Generalized winding number of a closed mesh at x (1 inside, 0 outside).
inline double windingNumber(const MatX3& V, const MatX3i& F, const Vec3& x) {
  double solid_angle = 0;
  for (int f = 0; f < F.rows(); ++f) {
    const Vec3 a = V.row(F(f, 0)).transpose() - x, b = V.row(F(f, 1)).transpose() - x,
               c = V.row(F(f, 2)).transpose() - x;
    const double la = a.norm(), lb = b.norm(), lc = c.norm();
    const double numerator = a.dot(b.cross(c));
    const double denominator = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
    solid_angle += 2 * std::atan2(numerator, denominator);
  }
  return solid_angle / (4 * M_PI);
}

/// #V × bones weights with every vertex fully on bone 0.
inline MatX weightsOnBoneZero(long vertices, int bones = 24) {
  MatX w = MatX::Zero(vertices, bones);
  w.col(0).setOnes();
  return w;
}

/// Structured tet mesh of the box [origin, origin + size]: n[0] × n[1] × n[2] cubes, each split
/// into 6 tets around its main diagonal (the Kuhn split, conforming between cubes), positively
/// oriented. Nodes are renumbered so that the boundary nodes come first (num_surface_nodes of
/// them), each group in lexicographic grid order. N = Π(n + 1), #T = 6 Π n.
inline TetMesh gridTetMesh(const Eigen::Vector3i& n, const Vec3& size,
                           const Vec3& origin = Vec3::Zero()) {
  const int nx = n[0] + 1, ny = n[1] + 1, nz = n[2] + 1;
  auto gridIndex = [&](int i, int j, int k) { return (k * ny + j) * nx + i; };
  const int total = nx * ny * nz;
  std::vector<int> renumber(total);
  std::vector<int> boundary, interior;
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        const bool on_boundary =
            i == 0 || j == 0 || k == 0 || i == nx - 1 || j == ny - 1 || k == nz - 1;
        (on_boundary ? boundary : interior).push_back(gridIndex(i, j, k));
      }
  TetMesh mesh;
  mesh.num_surface_nodes = int(boundary.size());
  mesh.nodes.resize(total, 3);
  int next = 0;
  for (const std::vector<int>* group : {&boundary, &interior})
    for (int g : *group) {
      renumber[g] = next;
      const int i = g % nx, j = (g / nx) % ny, k = g / (nx * ny);
      mesh.nodes.row(next++) = (origin + Vec3(size.x() * i / n[0], size.y() * j / n[1],
                                              size.z() * k / n[2]))
                                   .transpose();
    }
  const int permutations[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2},
                                  {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  mesh.tets.resize(6 * n[0] * n[1] * n[2], 4);
  int t = 0;
  for (int k = 0; k < n[2]; ++k)
    for (int j = 0; j < n[1]; ++j)
      for (int i = 0; i < n[0]; ++i)
        for (const auto& axes : permutations) {
          // A monotone path from the cube's corner (i, j, k) to its opposite corner.
          int corner[3] = {i, j, k};
          int tet[4];
          tet[0] = renumber[gridIndex(corner[0], corner[1], corner[2])];
          for (int step = 0; step < 3; ++step) {
            ++corner[axes[step]];
            tet[step + 1] = renumber[gridIndex(corner[0], corner[1], corner[2])];
          }
          const Vec3 x0 = mesh.nodes.row(tet[0]);
          const double det = (mesh.nodes.row(tet[1]).transpose() - x0)
                                 .cross(mesh.nodes.row(tet[2]).transpose() - x0)
                                 .dot(mesh.nodes.row(tet[3]).transpose() - x0);
          if (det < 0) std::swap(tet[2], tet[3]);
          mesh.tets.row(t++) << tet[0], tet[1], tet[2], tet[3];
        }
  return mesh;
}

/// Exact distance of a point inside the axis-aligned box [origin, origin + size] to its boundary.
inline double distanceInsideBox(const Vec3& x, const Vec3& size, const Vec3& origin = Vec3::Zero()) {
  const Vec3 low = x - origin, high = origin + size - x;
  return std::min(low.minCoeff(), high.minCoeff());
}

/// A "limb": a box of 0.12 × 0.12 × 0.40 m around the z axis (z from 0 to 0.4) with a two-bone
/// skeleton on its axis (joint 0 at z = 0.02, its child joint 1 at z = 0.2) and smooth weights
/// that blend from bone 0 to bone 1 around z = 0.2.
struct Limb {
  TetMesh mesh;
  Vec3 size = Vec3(0.12, 0.12, 0.40), origin = Vec3(-0.06, -0.06, 0.0);
  MatX3 joints;              // 2 × 3
  std::vector<int> parents;  // {−1, 0}
  MatX weights;              // #N × 2
};
inline Limb makeLimb(const Eigen::Vector3i& cells = Eigen::Vector3i(6, 6, 20)) {
  Limb limb;
  limb.mesh = gridTetMesh(cells, limb.size, limb.origin);
  limb.joints.resize(2, 3);
  limb.joints << 0, 0, 0.02, 0, 0, 0.2;
  limb.parents = {-1, 0};
  limb.weights.resize(limb.mesh.numNodes(), 2);
  for (int i = 0; i < limb.mesh.numNodes(); ++i) {
    const double s = 1 / (1 + std::exp(-(limb.mesh.nodes(i, 2) - 0.2) / 0.03));
    limb.weights.row(i) << 1 - s, s;
  }
  return limb;
}

}  // namespace flsh::test
