// Validity checks of closed triangle meshes, shared by the synthetic body and mesher tests:
// closed, manifold, genus 0, connected, consistently oriented outwards, non-degenerate and
// free of self-intersections.
#pragma once

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <map>
#include <sstream>
#include <unordered_map>
#include <utility>
#include <vector>

#include "flsh/core/types.h"

namespace flsh::test {

struct MeshQuality {
  double min_angle_deg = 0;
  double min_area = 0;
  double min_edge = 0, max_edge = 0, mean_edge = 0;
};

inline MeshQuality meshQuality(const MatX3& V, const MatX3i& F) {
  MeshQuality q;
  q.min_angle_deg = 180;
  q.min_area = std::numeric_limits<double>::infinity();
  q.min_edge = std::numeric_limits<double>::infinity();
  double total = 0;
  for (int f = 0; f < F.rows(); ++f) {
    for (int e = 0; e < 3; ++e) {
      const Vec3 a = V.row(F(f, e)), b = V.row(F(f, (e + 1) % 3)), c = V.row(F(f, (e + 2) % 3));
      const Vec3 u = b - a, w = c - a;
      const double angle = std::atan2(u.cross(w).norm(), u.dot(w)) * 180.0 / M_PI;
      q.min_angle_deg = std::min(q.min_angle_deg, angle);
      q.min_edge = std::min(q.min_edge, u.norm());
      q.max_edge = std::max(q.max_edge, u.norm());
      total += u.norm();
    }
    const Vec3 a = V.row(F(f, 0)), b = V.row(F(f, 1)), c = V.row(F(f, 2));
    q.min_area = std::min(q.min_area, 0.5 * (b - a).cross(c - a).norm());
  }
  q.mean_edge = total / (3.0 * F.rows());
  return q;
}

/// Signed enclosed volume (positive for outward, counter-clockwise faces), m³.
inline double enclosedVolume(const MatX3& V, const MatX3i& F) {
  double vol = 0;
  for (int f = 0; f < F.rows(); ++f) {
    const Vec3 a = V.row(F(f, 0)), b = V.row(F(f, 1)), c = V.row(F(f, 2));
    vol += a.dot(b.cross(c)) / 6.0;
  }
  return vol;
}

/// Closed (every edge in two faces, once in each direction = consistent orientation),
/// manifold (each vertex's link is one cycle), connected, Euler characteristic 2, positive
/// volume, no zero-area face.
inline ::testing::AssertionResult isClosedGenus0Manifold(const MatX3& V, const MatX3i& F) {
  const long nv = V.rows(), nf = F.rows();
  if (F.minCoeff() < 0 || F.maxCoeff() >= nv)
    return ::testing::AssertionFailure() << "face index out of range";
  std::map<std::pair<int, int>, int> directed;
  for (int f = 0; f < nf; ++f)
    for (int e = 0; e < 3; ++e) {
      const int a = F(f, e), b = F(f, (e + 1) % 3);
      if (a == b) return ::testing::AssertionFailure() << "face " << f << " repeats a vertex";
      if (++directed[{a, b}] > 1)
        return ::testing::AssertionFailure()
               << "directed edge " << a << "->" << b << " used twice (orientation or non-manifold)";
    }
  for (const auto& [edge, count] : directed)
    if (!directed.count({edge.second, edge.first}))
      return ::testing::AssertionFailure()
             << "edge " << edge.first << "-" << edge.second << " is on the boundary";
  const long ne = long(directed.size()) / 2;
  if (nv - ne + nf != 2)
    return ::testing::AssertionFailure()
           << "Euler characteristic V - E + F = " << nv - ne + nf << ", expected 2";
  // Manifold vertices: around each vertex, the map b -> c of its faces (v, b, c) is one cycle.
  std::vector<std::vector<std::pair<int, int>>> link(nv);
  for (int f = 0; f < nf; ++f)
    for (int e = 0; e < 3; ++e) link[F(f, e)].push_back({F(f, (e + 1) % 3), F(f, (e + 2) % 3)});
  for (long v = 0; v < nv; ++v) {
    if (link[v].size() < 3)
      return ::testing::AssertionFailure()
             << "vertex " << v << " has " << link[v].size() << " faces";
    std::unordered_map<int, int> next;
    for (const auto& [b, c] : link[v]) next[b] = c;
    int steps = 0, start = link[v][0].first, cur = start;
    do {
      auto it = next.find(cur);
      if (it == next.end()) return ::testing::AssertionFailure() << "vertex " << v << " link open";
      cur = it->second;
      ++steps;
    } while (cur != start && steps <= int(link[v].size()));
    if (steps != int(link[v].size()))
      return ::testing::AssertionFailure()
             << "vertex " << v << " is non-manifold (link of " << link[v].size()
             << " faces has a cycle of " << steps << ")";
  }
  // One connected component.
  std::vector<std::vector<int>> nbrs(nv);
  for (const auto& [edge, count] : directed) nbrs[edge.first].push_back(edge.second);
  std::vector<char> seen(nv, 0);
  std::vector<int> stack = {0};
  seen[0] = 1;
  long reached = 1;
  while (!stack.empty()) {
    const int v = stack.back();
    stack.pop_back();
    for (int n : nbrs[v])
      if (!seen[n]) {
        seen[n] = 1;
        ++reached;
        stack.push_back(n);
      }
  }
  if (reached != nv)
    return ::testing::AssertionFailure()
           << "only " << reached << " of " << nv << " vertices are connected to vertex 0";
  const double volume = enclosedVolume(V, F);
  if (!(volume > 0))
    return ::testing::AssertionFailure() << "enclosed volume " << volume << " is not positive";
  if (!(meshQuality(V, F).min_area > 0))
    return ::testing::AssertionFailure() << "a face has zero area";
  return ::testing::AssertionSuccess();
}

namespace detail {

// Does segment [p, q] cross triangle (a, b, c)? (Möller–Trumbore with t ∈ [0, 1].)
inline bool segmentHitsTriangle(const Vec3& p, const Vec3& q, const Vec3& a, const Vec3& b,
                                const Vec3& c) {
  const Vec3 d = q - p, e1 = b - a, e2 = c - a;
  const Vec3 h = d.cross(e2);
  const double det = e1.dot(h);
  if (std::abs(det) < 1e-300) return false;
  const double inv = 1.0 / det;
  const Vec3 s = p - a;
  const double u = inv * s.dot(h);
  if (u < 0 || u > 1) return false;
  const Vec3 qv = s.cross(e1);
  const double v = inv * d.dot(qv);
  if (v < 0 || u + v > 1) return false;
  const double t = inv * e2.dot(qv);
  return t >= 0 && t <= 1;
}

}  // namespace detail

/// Number of pairs of faces sharing no vertex that intersect (an edge of one crosses the
/// other). Uniform-grid broad phase.
inline long countSelfIntersections(const MatX3& V, const MatX3i& F) {
  const long nf = F.rows();
  const double cell = 2.0 * meshQuality(V, F).mean_edge;
  const Vec3 lo = V.colwise().minCoeff().transpose();
  std::unordered_map<std::int64_t, std::vector<int>> grid;
  auto key = [](long i, long j, long k) { return (i * 4096 + j) * 4096 + k; };
  std::vector<Eigen::AlignedBox3d> boxes(nf);
  for (int f = 0; f < nf; ++f) {
    for (int c = 0; c < 3; ++c) boxes[f].extend(Vec3(V.row(F(f, c)).transpose()));
    const Eigen::Vector3i b0 = ((boxes[f].min() - lo) / cell).array().floor().cast<int>();
    const Eigen::Vector3i b1 = ((boxes[f].max() - lo) / cell).array().floor().cast<int>();
    for (int i = b0.x(); i <= b1.x(); ++i)
      for (int j = b0.y(); j <= b1.y(); ++j)
        for (int k = b0.z(); k <= b1.z(); ++k) grid[key(i, j, k)].push_back(f);
  }
  std::vector<std::pair<int, int>> hits;
  for (const auto& [k, faces] : grid)
    for (std::size_t x = 0; x < faces.size(); ++x)
      for (std::size_t y = x + 1; y < faces.size(); ++y) {
        const int f = std::min(faces[x], faces[y]), g = std::max(faces[x], faces[y]);
        if (!boxes[f].intersects(boxes[g])) continue;
        bool shared = false;
        for (int a = 0; a < 3; ++a)
          for (int b = 0; b < 3; ++b) shared |= F(f, a) == F(g, b);
        if (shared) continue;
        bool hit = false;
        for (int e = 0; e < 3 && !hit; ++e) {
          hit |= detail::segmentHitsTriangle(V.row(F(f, e)), V.row(F(f, (e + 1) % 3)),
                                             V.row(F(g, 0)), V.row(F(g, 1)), V.row(F(g, 2)));
          hit |= detail::segmentHitsTriangle(V.row(F(g, e)), V.row(F(g, (e + 1) % 3)),
                                             V.row(F(f, 0)), V.row(F(f, 1)), V.row(F(f, 2)));
        }
        if (hit) hits.push_back({f, g});
      }
  std::sort(hits.begin(), hits.end());
  hits.erase(std::unique(hits.begin(), hits.end()), hits.end());
  return long(hits.size());
}

}  // namespace flsh::test
