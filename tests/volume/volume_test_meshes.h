// Shared inputs of the volume tests: the small synthetic body (generated once per binary),
// closed analytic meshes (box, icosphere), their exact solid integrals and an inside test.
#pragma once

#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <map>
#include <memory>
#include <utility>

#include "flsh/body/body_model.h"
#include "flsh/body/synthetic_body.h"
#include "flsh/core/types.h"

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

}  // namespace flsh::test
