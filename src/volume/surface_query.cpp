// Boundary faces of tet meshes and closest points on triangle surfaces (surface_query.h).
#include "volume/surface_query.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <sstream>
#include <string>
#include <unordered_map>

#include "flsh/core/error.h"

namespace flsh::detail {

namespace {

// Outward faces of a positively oriented tet (x0, x1, x2, x3): face k is opposite node 3 − k.
constexpr int kTetFaces[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
constexpr int kLeafSize = 4;

/// Closest point of triangle (a, b, c) to p and its barycentric weights (Voronoi regions of the
/// vertices, edges and face, in that order).
Vec3 closestOnTriangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c, Vec3& bary) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return bary = Vec3(1, 0, 0), a;
  const Vec3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return bary = Vec3(0, 1, 0), b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) {
    const double t = d1 / (d1 - d3);
    bary = Vec3(1 - t, t, 0);
    return a + t * ab;
  }
  const Vec3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return bary = Vec3(0, 0, 1), c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) {
    const double t = d2 / (d2 - d6);
    bary = Vec3(1 - t, 0, t);
    return a + t * ac;
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    const double t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    bary = Vec3(0, 1 - t, t);
    return b + t * (c - b);
  }
  const double denominator = va + vb + vc;
  if (!(std::abs(denominator) > 0)) {  // degenerate triangle: nearest of its vertices
    const double da = ap.squaredNorm(), db = bp.squaredNorm(), dc = cp.squaredNorm();
    if (da <= db && da <= dc) return bary = Vec3(1, 0, 0), a;
    if (db <= dc) return bary = Vec3(0, 1, 0), b;
    return bary = Vec3(0, 0, 1), c;
  }
  const double v = vb / denominator, w = vc / denominator;
  bary = Vec3(1 - v - w, v, w);
  return a + v * ab + w * ac;
}

std::string tetString(const TetMesh& mesh, int t) {
  return "tet " + std::to_string(t) + " (" + std::to_string(mesh.tets(t, 0)) + ", " +
         std::to_string(mesh.tets(t, 1)) + ", " + std::to_string(mesh.tets(t, 2)) + ", " +
         std::to_string(mesh.tets(t, 3)) + ")";
}

}  // namespace

void checkTetMesh(const TetMesh& mesh, const MatX3& nodes, const char* who,
                  bool require_positive_volume) {
  const std::string fn = std::string(who) + ": ";
  const int n = mesh.numNodes();
  if (nodes.rows() != n)
    throw InputError(fn + "nodes have " + std::to_string(nodes.rows()) + " rows, expected " +
                     std::to_string(n) + " (#N of the tet mesh)");
  if (!nodes.allFinite()) throw InputError(fn + "node positions contain NaN or Inf");
  if (mesh.num_surface_nodes < 0 || mesh.num_surface_nodes > n)
    throw InputError(fn + "num_surface_nodes = " + std::to_string(mesh.num_surface_nodes) +
                     ", expected 0..#N = " + std::to_string(n));
  if (mesh.numTets() == 0) throw InputError(fn + "the tet mesh has 0 tets");
  std::vector<char> used(n, 0);
  for (int t = 0; t < mesh.numTets(); ++t) {
    for (int k = 0; k < 4; ++k) {
      const int i = mesh.tets(t, k);
      if (i < 0 || i >= n)
        throw InputError(fn + tetString(mesh, t) + " has node index " + std::to_string(i) +
                         ", expected 0.." + std::to_string(n - 1));
      for (int l = 0; l < k; ++l)
        if (mesh.tets(t, l) == i) throw InputError(fn + tetString(mesh, t) + " repeats a node");
      used[i] = 1;
    }
    if (!require_positive_volume) continue;
    const Vec3 x0 = nodes.row(mesh.tets(t, 0));
    const double det = (nodes.row(mesh.tets(t, 1)).transpose() - x0)
                           .cross(nodes.row(mesh.tets(t, 2)).transpose() - x0)
                           .dot(nodes.row(mesh.tets(t, 3)).transpose() - x0);
    if (!(det > 0)) {
      std::ostringstream volume;
      volume << det / 6;  // general format: tiny volumes stay readable (std::to_string → 0.000000)
      throw InputError(fn + tetString(mesh, t) + " has signed volume " + volume.str() +
                       " m³, expected > 0 (positively oriented, not degenerate)");
    }
  }
  for (int i = 0; i < n; ++i)
    if (!used[i])
      throw InputError(fn + "node " + std::to_string(i) +
                       " belongs to no tet, expected every node "
                       "to be used");
}

MatX3i outwardBoundaryFaces(const TetMesh& mesh, const char* who, std::vector<int>* owners) {
  // Key: the sorted node triple; value: (first owning face as tet·4 + k, count).
  struct Entry {
    int face = 0, count = 0;
  };
  const long n = mesh.numNodes();
  auto key = [n](std::array<int, 3> f) {
    std::sort(f.begin(), f.end());
    return (long long)(f[0]) * n * n + (long long)(f[1]) * n + f[2];
  };
  std::unordered_map<long long, Entry> faces;
  faces.reserve(size_t(mesh.numTets()) * 4);
  for (int t = 0; t < mesh.numTets(); ++t)
    for (int k = 0; k < 4; ++k) {
      Entry& e = faces[key({mesh.tets(t, kTetFaces[k][0]), mesh.tets(t, kTetFaces[k][1]),
                            mesh.tets(t, kTetFaces[k][2])})];
      if (e.count++ == 0) e.face = 4 * t + k;
      if (e.count > 2)
        throw InputError(std::string(who) + ": a face of " + tetString(mesh, t) +
                         " belongs to more than two tets (non-manifold tet mesh)");
    }
  std::vector<int> boundary;
  for (const auto& [k, e] : faces)
    if (e.count == 1) boundary.push_back(e.face);
  std::sort(boundary.begin(), boundary.end());  // tet order: independent of hashing
  MatX3i F(boundary.size(), 3);
  if (owners) owners->resize(boundary.size());
  for (size_t b = 0; b < boundary.size(); ++b) {
    const int t = boundary[b] / 4, k = boundary[b] % 4;
    if (owners) (*owners)[b] = t;
    for (int c = 0; c < 3; ++c) {
      F(b, c) = mesh.tets(t, kTetFaces[k][c]);
      if (F(b, c) >= mesh.num_surface_nodes)
        throw InputError(std::string(who) + ": boundary face of " + tetString(mesh, t) +
                         " uses node " + std::to_string(F(b, c)) +
                         ", expected surface nodes only (0.." +
                         std::to_string(mesh.num_surface_nodes - 1) + ")");
    }
  }
  return F;
}

MatX3 vertexNormals(const MatX3& V, const MatX3i& F) {
  MatX3 N = MatX3::Zero(V.rows(), 3);
  for (int f = 0; f < F.rows(); ++f) {
    const Vec3 a = V.row(F(f, 0)), b = V.row(F(f, 1)), c = V.row(F(f, 2));
    const Vec3 area_normal = (b - a).cross(c - a);  // twice the area times the unit normal
    for (int k = 0; k < 3; ++k) N.row(F(f, k)) += area_normal.transpose();
  }
  for (int v = 0; v < N.rows(); ++v) {
    const double length = N.row(v).norm();
    if (length > 0) N.row(v) /= length;
  }
  return N;
}

SurfaceDistance::SurfaceDistance(const MatX3& V, const MatX3i& F) : V_(V), F_(F) {
  if (F.rows() == 0) throw InputError("SurfaceDistance: the surface has 0 triangles");
  order_.resize(F.rows());
  for (int f = 0; f < F.rows(); ++f) order_[f] = f;
  nodes_.reserve(2 * F.rows() / kLeafSize + 2);
  build(0, int(F.rows()));
}

int SurfaceDistance::build(int begin, int end) {
  const int index = int(nodes_.size());
  nodes_.emplace_back();
  Eigen::AlignedBox3d box, centres;
  for (int i = begin; i < end; ++i) {
    const int f = order_[i];
    for (int c = 0; c < 3; ++c) box.extend(Vec3(V_.row(F_(f, c))));
    centres.extend(Vec3((V_.row(F_(f, 0)) + V_.row(F_(f, 1)) + V_.row(F_(f, 2))) / 3));
  }
  nodes_[index].box = box;
  if (end - begin <= kLeafSize) {
    nodes_[index].begin = begin;
    nodes_[index].end = end;
    return index;
  }
  int axis = 0;
  centres.sizes().maxCoeff(&axis);
  const int middle = (begin + end) / 2;
  auto centre = [&](int f) { return V_(F_(f, 0), axis) + V_(F_(f, 1), axis) + V_(F_(f, 2), axis); };
  // Ties broken by index so that the tree (and hence tie-breaking of queries) is deterministic.
  std::nth_element(order_.begin() + begin, order_.begin() + middle, order_.begin() + end,
                   [&](int a, int b) {
                     const double ca = centre(a), cb = centre(b);
                     return ca < cb || (ca == cb && a < b);
                   });
  const int left = build(begin, middle);
  const int right = build(middle, end);
  nodes_[index].left = left;
  nodes_[index].right = right;
  return index;
}

SurfaceDistance::Hit SurfaceDistance::closest(const Vec3& x) const {
  Hit best;
  double best_squared = std::numeric_limits<double>::infinity();
  int stack[128];
  int top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const Node& node = nodes_[stack[--top]];
    if (node.box.squaredExteriorDistance(x) >= best_squared) continue;
    if (node.left < 0) {
      for (int i = node.begin; i < node.end; ++i) {
        const int f = order_[i];
        Vec3 bary;
        const Vec3 p =
            closestOnTriangle(x, V_.row(F_(f, 0)), V_.row(F_(f, 1)), V_.row(F_(f, 2)), bary);
        const double squared = (p - x).squaredNorm();
        if (squared < best_squared) {
          best_squared = squared;
          best.point = p;
          best.face = f;
          best.barycentric = bary;
        }
      }
      continue;
    }
    // Visit the nearer child first (pushed last).
    const double dl = nodes_[node.left].box.squaredExteriorDistance(x);
    const double dr = nodes_[node.right].box.squaredExteriorDistance(x);
    if (dl <= dr) {
      stack[top++] = node.right;
      stack[top++] = node.left;
    } else {
      stack[top++] = node.left;
      stack[top++] = node.right;
    }
  }
  best.distance = std::sqrt(best_squared);
  return best;
}

}  // namespace flsh::detail
