// Tetrahedral mesh of a closed surface: input checks, the choice of the interior node size,
// quality measures and validation. The CGAL stages live in src/cgal/tetrahedralize.cpp.
#include "flsh/volume/tet_mesh.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <string>
#include <tuple>
#include <unordered_map>
#include <vector>

#include "cgal/tetrahedralize.h"
#include "core/seconds_since.h"
#include "flsh/core/error.h"
#include "volume/tet_mesh_internal.h"

namespace flsh {
namespace {

// Interior Mesh_3 vertices closer than this × the nearest surface triangle's mean edge length
// are dropped: closer ones would take the place of surface faces in the Delaunay mesh.
constexpr double kClearance = 0.6;
// Interior nodes per surface vertex at resolution 1 (≈ 3100 for a 6890-vertex body).
constexpr double kInteriorNodesPerSurfaceVertex = 0.45;
// Enclosed volume per kept interior node is about this × cell_size³ at the default density
// (measured on the synthetic body: 2.0 at 6890 vertices, 2.5 at 600); the first guess of the size.
constexpr double kVolumePerNodeOverCellSizeCubed = 2.2;
// The kept count falls faster than cell_size⁻³ (Mesh_3 vertices near the surface are surface
// vertices, and the discarded layer is a larger share of coarser meshes): about cell_size^−4.5
// on the synthetic body. The exponent of the first size correction; later ones use the slope
// measured between runs.
constexpr double kCountExponent = -4.5;
// Accepted interior node count relative to the target, and at most this many Mesh_3 runs.
constexpr double kCountTolerance = 0.12;
constexpr int kMaxInteriorRuns = 4;

using detail::secondsSince;
std::string tripleString(int a, int b, int c) {
  return "(" + std::to_string(a) + ", " + std::to_string(b) + ", " + std::to_string(c) + ")";
}

Vec3 rowOf(const MatX3& X, int i) { return X.row(i).transpose(); }

/// A triangle rotated to start at its smallest index (cyclic order, hence orientation, kept).
std::array<int, 3> canonicalTriangle(int a, int b, int c) {
  if (b < a && b < c) return {b, c, a};
  if (c < a && c < b) return {c, a, b};
  return {a, b, c};
}

double signedVolume(const Vec3& x0, const Vec3& x1, const Vec3& x2, const Vec3& x3) {
  return (x1 - x0).cross(x2 - x0).dot(x3 - x0) / 6.0;
}

// Closed, oriented 2-manifold checks of the input surface; throws InputError naming the
// first problem found.
void checkSurface(const MatX3& V, const MatX3i& F) {
  const std::string where = "tetrahedralizeSurface: ";
  if (V.rows() < 4)
    throw InputError(where + "V must have at least 4 vertices (#V × 3), got " +
                     shapeString({long(V.rows()), 3}));
  if (F.rows() < 4)
    throw InputError(where + "F must have at least 4 triangles (#F × 3), got " +
                     shapeString({long(F.rows()), 3}));
  if (!V.allFinite()) throw InputError(where + "V contains NaN or Inf");
  const int n = int(V.rows());
  std::vector<int> uses(size_t(n), 0);
  for (int f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      if (F(f, k) < 0 || F(f, k) >= n)
        throw InputError(where + "F(" + std::to_string(f) + ", " + std::to_string(k) +
                         ") = " + std::to_string(F(f, k)) + " is out of range [0, " +
                         std::to_string(n) + ")");
      ++uses[size_t(F(f, k))];
    }
    if (F(f, 0) == F(f, 1) || F(f, 1) == F(f, 2) || F(f, 2) == F(f, 0))
      throw InputError(where + "face " + std::to_string(f) + " " +
                       tripleString(F(f, 0), F(f, 1), F(f, 2)) + " repeats a vertex");
  }
  for (int i = 0; i < n; ++i)
    if (uses[size_t(i)] == 0)
      throw InputError(where + "vertex " + std::to_string(i) +
                       " is used by no face; expected every vertex of V on the surface");

  // Every directed edge once and its reverse once: closed, edge-manifold, consistently oriented.
  std::unordered_map<uint64_t, int> directed;  // (from, to) → face
  directed.reserve(size_t(3 * F.rows()));
  const auto key = [](int from, int to) { return (uint64_t(uint32_t(from)) << 32) | uint32_t(to); };
  for (int f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int from = F(f, k), to = F(f, (k + 1) % 3);
      const auto [it, inserted] = directed.emplace(key(from, to), f);
      if (!inserted)
        throw InputError(where + "edge (" + std::to_string(from) + ", " + std::to_string(to) +
                         ") has the same direction in faces " + std::to_string(it->second) +
                         " and " + std::to_string(f) +
                         "; expected a consistently oriented manifold surface (each edge in "
                         "exactly two faces, once in each direction)");
    }
  }
  for (int f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int from = F(f, k), to = F(f, (k + 1) % 3);
      if (!directed.count(key(to, from)))
        throw InputError(where + "edge (" + std::to_string(from) + ", " + std::to_string(to) +
                         ") of face " + std::to_string(f) +
                         " has no opposite face; expected a closed surface (the surface is open "
                         "there, or the neighbouring face is inconsistently oriented, or the "
                         "edge is non-manifold)");
    }
  }
  // Vertex-manifold: the faces around each vertex form one fan. Around v, face (v, x, y) links
  // x → y; a closed fan is one cycle through all of v's faces.
  std::vector<std::vector<std::pair<int, int>>> links(static_cast<size_t>(n));
  for (int f = 0; f < F.rows(); ++f)
    for (int k = 0; k < 3; ++k)
      links[size_t(F(f, k))].emplace_back(F(f, (k + 1) % 3), F(f, (k + 2) % 3));
  for (int v = 0; v < n; ++v) {
    auto& link = links[size_t(v)];
    std::sort(link.begin(), link.end());
    int current = link.front().first, steps = 0;
    do {
      const auto it = std::lower_bound(link.begin(), link.end(), std::make_pair(current, -1));
      current = it->second;  // exists: every directed edge has its reverse
      ++steps;
    } while (current != link.front().first && steps <= int(link.size()));
    if (steps != int(link.size()))
      throw InputError(where + "vertex " + std::to_string(v) + " is non-manifold: its " +
                       std::to_string(link.size()) + " faces form more than one fan");
  }

  double volume = 0;
  for (int f = 0; f < F.rows(); ++f)
    volume += signedVolume(Vec3::Zero(), rowOf(V, F(f, 0)), rowOf(V, F(f, 1)), rowOf(V, F(f, 2)));
  if (!(volume > 0))
    throw InputError(where + "the enclosed volume is " + std::to_string(volume) +
                     " m³; expected a positive volume (triangles counter-clockwise seen from "
                     "outside — is the orientation inverted?)");
}

}  // namespace

TetMesh tetrahedralizeSurface(const MatX3& V, const MatX3i& F, const TetMeshOptions& options,
                              TetMeshTimings* timings) {
  const auto start = std::chrono::steady_clock::now();
  if (!std::isfinite(options.resolution) || options.resolution < 0.01 || options.resolution > 100)
    throw InputError(
        "tetrahedralizeSurface: options.resolution must be finite in [0.01, 100], got " +
        std::to_string(options.resolution));
  checkSurface(V, F);
  const auto intersection = cgal::firstSelfIntersection(V, F);
  if (intersection.first >= 0) {
    const int f = intersection.first, g = intersection.second;
    throw InputError("tetrahedralizeSurface: the surface intersects itself: faces " +
                     std::to_string(f) + " " + tripleString(F(f, 0), F(f, 1), F(f, 2)) + " and " +
                     std::to_string(g) + " " + tripleString(F(g, 0), F(g, 1), F(g, 2)));
  }
  TetMeshTimings local;
  TetMeshTimings& t = timings ? *timings : local;
  t = TetMeshTimings{};

  // Interior nodes: a cell size from the enclosed volume, then secant steps on log(count) versus
  // log(cell size) until the count is within tolerance of the target; the closest run is kept.
  double volume = 0;
  for (int f = 0; f < F.rows(); ++f)
    volume += signedVolume(Vec3::Zero(), rowOf(V, F(f, 0)), rowOf(V, F(f, 1)), rowOf(V, F(f, 2)));
  const double target = kInteriorNodesPerSurfaceVertex * double(V.rows()) * options.resolution;
  double cell_size = std::cbrt(volume / (kVolumePerNodeOverCellSizeCubed * target));
  auto stage = std::chrono::steady_clock::now();
  MatX3 interior;
  double best_error = std::numeric_limits<double>::infinity();
  double previous_size = 0, previous_count = 0;
  for (int run = 0; run < kMaxInteriorRuns; ++run) {
    MatX3 points = cgal::meshInteriorPoints(V, F, cell_size, kClearance, options.seed);
    const double count = std::max(double(points.rows()), 0.5);  // 0.5: keeps the logs finite
    const double error = std::abs(std::log(count / target));
    if (error < best_error) {
      best_error = error;
      interior = std::move(points);
    }
    if (std::abs(count / target - 1) <= kCountTolerance) break;
    // Nothing kept twice: the body is too thin for the clearance, finer cells cannot help.
    if (count < 1 && run > 0) break;
    double exponent = kCountExponent;
    if (run > 0 && count != previous_count)
      exponent = std::clamp(std::log(count / previous_count) / std::log(cell_size / previous_size),
                            -8.0, -2.0);
    previous_size = cell_size;
    previous_count = count;
    cell_size *= std::clamp(std::pow(target / count, 1 / exponent), 0.5, 2.0);
  }
  t.interior_points = secondsSince(stage);

  TetMesh mesh;
  mesh.num_surface_nodes = int(V.rows());
  mesh.nodes.resize(V.rows() + interior.rows(), 3);
  mesh.nodes.topRows(V.rows()) = V;
  mesh.nodes.bottomRows(interior.rows()) = interior;

  cgal::BoundaryConformingTets result = cgal::boundaryConformingTets(mesh.nodes, F);
  t.delaunay = result.delaunay_seconds;
  t.recovery = result.recovery_seconds;
  t.recovered_faces = result.recovered_faces;
  if (result.unrecovered_faces > 0) {
    const int f = result.example_unrecovered;
    throw Error("tetrahedralizeSurface: " + std::to_string(result.unrecovered_faces) + " of the " +
                std::to_string(result.missing_faces) +
                " surface faces missing from the Delaunay tetrahedralization could not be "
                "recovered by flips (e.g. face " +
                std::to_string(f) + " " + tripleString(F(f, 0), F(f, 1), F(f, 2)) +
                "); the surface may be too close to self-intersecting or have coplanar "
                "faces whose diagonals the Delaunay mesh crosses");
  }

  // Canonical order, so that the output does not depend on CGAL's memory layout.
  std::vector<std::array<int, 4>> tets(size_t(result.tets.rows()));
  for (Eigen::Index r = 0; r < result.tets.rows(); ++r)
    tets[size_t(r)] = {result.tets(r, 0), result.tets(r, 1), result.tets(r, 2), result.tets(r, 3)};
  mesh.tets = canonicalTets(std::move(tets));

  if (options.improve_quality) {
    stage = std::chrono::steady_clock::now();
    improveTetMeshQuality(mesh);
    t.quality = secondsSince(stage);
  }
  validateTetMesh(mesh, F);
  t.total = secondsSince(start);
  return mesh;
}

VecX tetVolumes(const TetMesh& mesh) {
  VecX volumes(mesh.tets.rows());
  for (Eigen::Index t = 0; t < mesh.tets.rows(); ++t)
    volumes[t] =
        signedVolume(rowOf(mesh.nodes, mesh.tets(t, 0)), rowOf(mesh.nodes, mesh.tets(t, 1)),
                     rowOf(mesh.nodes, mesh.tets(t, 2)), rowOf(mesh.nodes, mesh.tets(t, 3)));
  return volumes;
}

MatX3i boundaryFaces(const MatX4i& tets) {
  // Outward faces of a positively oriented tet (x0, x1, x2, x3).
  static constexpr int kFaces[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
  struct Face {
    std::array<int, 3> sorted, oriented;
  };
  std::vector<Face> faces;
  faces.reserve(size_t(4 * tets.rows()));
  for (Eigen::Index t = 0; t < tets.rows(); ++t) {
    for (const auto& local : kFaces) {
      Face face;
      face.oriented = canonicalTriangle(tets(t, local[0]), tets(t, local[1]), tets(t, local[2]));
      face.sorted = face.oriented;
      std::sort(face.sorted.begin(), face.sorted.end());
      faces.push_back(face);
    }
  }
  std::sort(faces.begin(), faces.end(), [](const Face& x, const Face& y) {
    return std::tie(x.sorted, x.oriented) < std::tie(y.sorted, y.oriented);
  });
  std::vector<std::array<int, 3>> boundary;
  for (size_t i = 0; i < faces.size();) {
    size_t j = i;
    while (j < faces.size() && faces[j].sorted == faces[i].sorted) ++j;
    const auto& s = faces[i].sorted;
    if (j - i == 1) {
      boundary.push_back(faces[i].oriented);
    } else if (j - i > 2) {
      throw Error("boundaryFaces: face " + tripleString(s[0], s[1], s[2]) + " belongs to " +
                  std::to_string(j - i) + " tets; expected at most 2 (a manifold tet mesh)");
    } else if (faces[i].oriented == faces[i + 1].oriented) {
      throw Error("boundaryFaces: face " + tripleString(s[0], s[1], s[2]) +
                  " has the same orientation in both of its tets; expected opposite (one of "
                  "the tets is inverted)");
    }
    i = j;
  }
  std::sort(boundary.begin(), boundary.end());
  MatX3i out(Eigen::Index(boundary.size()), 3);
  for (size_t i = 0; i < boundary.size(); ++i)
    out.row(Eigen::Index(i)) << boundary[i][0], boundary[i][1], boundary[i][2];
  return out;
}

void validateTetMesh(const TetMesh& mesh, const MatX3i& F) {
  const std::string where = "validateTetMesh: ";
  const int n = mesh.numNodes(), surface_nodes = mesh.num_surface_nodes;
  if (!mesh.nodes.allFinite()) throw Error(where + "nodes contain NaN or Inf");
  if (surface_nodes < 0 || surface_nodes > n)
    throw Error(where + "num_surface_nodes = " + std::to_string(surface_nodes) +
                " is outside [0, " + std::to_string(n) + "]");
  std::vector<char> used(size_t(n), 0);
  for (Eigen::Index t = 0; t < mesh.tets.rows(); ++t) {
    for (int k = 0; k < 4; ++k) {
      const int i = mesh.tets(t, k);
      if (i < 0 || i >= n)
        throw Error(where + "tet " + std::to_string(t) + " has node index " + std::to_string(i) +
                    " outside [0, " + std::to_string(n) + ")");
      for (int l = 0; l < k; ++l)
        if (mesh.tets(t, l) == i)
          throw Error(where + "tet " + std::to_string(t) + " repeats node " + std::to_string(i));
      used[size_t(i)] = 1;
    }
  }
  const VecX volumes = tetVolumes(mesh);
  for (Eigen::Index t = 0; t < volumes.size(); ++t)
    if (!(volumes[t] > 0))
      throw Error(where + "tet " + std::to_string(t) + " (" + std::to_string(mesh.tets(t, 0)) +
                  ", " + std::to_string(mesh.tets(t, 1)) + ", " + std::to_string(mesh.tets(t, 2)) +
                  ", " + std::to_string(mesh.tets(t, 3)) + ") has volume " +
                  std::to_string(volumes[t]) + " m³; expected > 0 (inverted or degenerate)");
  for (int i = 0; i < n; ++i)
    if (!used[size_t(i)]) throw Error(where + "node " + std::to_string(i) + " is used by no tet");

  std::vector<char> on_surface(size_t(surface_nodes), 0);
  std::vector<std::array<int, 3>> expected(size_t(F.rows()));
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      if (F(f, k) < 0 || F(f, k) >= surface_nodes)
        throw Error(where + "F(" + std::to_string(f) + ", " + std::to_string(k) +
                    ") = " + std::to_string(F(f, k)) + " is not a surface node [0, " +
                    std::to_string(surface_nodes) + ")");
      on_surface[size_t(F(f, k))] = 1;
    }
    expected[size_t(f)] = canonicalTriangle(F(f, 0), F(f, 1), F(f, 2));
  }
  for (int i = 0; i < surface_nodes; ++i)
    if (!on_surface[size_t(i)])
      throw Error(where + "surface node " + std::to_string(i) + " is in no face of F");
  std::sort(expected.begin(), expected.end());
  const MatX3i boundary = boundaryFaces(mesh.tets);
  size_t i = 0;
  Eigen::Index j = 0;
  while (i < expected.size() || j < boundary.rows()) {
    const bool has_expected = i < expected.size(), has_boundary = j < boundary.rows();
    std::array<int, 3> b{};
    if (has_boundary) b = {boundary(j, 0), boundary(j, 1), boundary(j, 2)};
    if (has_expected && has_boundary && expected[i] == b) {
      ++i;
      ++j;
    } else if (has_expected && (!has_boundary || expected[i] < b)) {
      throw Error(where + "surface face " +
                  tripleString(expected[i][0], expected[i][1], expected[i][2]) +
                  " is not a boundary face of the tets (as an outward triangle); boundary has " +
                  std::to_string(boundary.rows()) + " faces, F has " + std::to_string(F.rows()));
    } else {
      throw Error(where + "boundary face " + tripleString(b[0], b[1], b[2]) +
                  " of the tets is not a face of F; boundary has " +
                  std::to_string(boundary.rows()) + " faces, F has " + std::to_string(F.rows()));
    }
  }
}

TetMeshQuality tetMeshQuality(const TetMesh& mesh) {
  TetMeshQuality q;
  if (mesh.tets.rows() == 0) return q;
  q.min_dihedral_deg = std::numeric_limits<double>::infinity();
  q.max_dihedral_deg = 0;
  q.min_volume = std::numeric_limits<double>::infinity();
  double ratio_sum = 0;
  static constexpr int kEdges[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};
  for (Eigen::Index t = 0; t < mesh.tets.rows(); ++t) {
    Vec3 x[4];
    for (int k = 0; k < 4; ++k) x[k] = rowOf(mesh.nodes, mesh.tets(t, k));
    const Vec3 a = x[1] - x[0], b = x[2] - x[0], c = x[3] - x[0];
    const double det = a.dot(b.cross(c));
    q.min_volume = std::min(q.min_volume, det / 6);
    // Area vectors of the faces opposite each vertex, all pointing outward.
    Vec3 normal[4] = {(x[2] - x[1]).cross(x[3] - x[1]), (x[3] - x[0]).cross(x[2] - x[0]),
                      (x[1] - x[0]).cross(x[3] - x[0]), (x[2] - x[0]).cross(x[1] - x[0])};
    double shortest = std::numeric_limits<double>::infinity();
    for (const auto& e : kEdges) {
      shortest = std::min(shortest, (x[e[0]] - x[e[1]]).norm());
      // The edge (i, j) is shared by the faces opposite the two other vertices k, l.
      int others[2], m = 0;
      for (int v = 0; v < 4; ++v)
        if (v != e[0] && v != e[1]) others[m++] = v;
      const Vec3& nk = normal[others[0]];
      const Vec3& nl = normal[others[1]];
      const double cosine = std::clamp(-nk.dot(nl) / (nk.norm() * nl.norm()), -1.0, 1.0);
      const double angle = std::acos(cosine) * 180.0 / M_PI;
      q.min_dihedral_deg = std::min(q.min_dihedral_deg, angle);
      q.max_dihedral_deg = std::max(q.max_dihedral_deg, angle);
    }
    // Circumcentre offset from x0: (|a|²(b×c) + |b|²(c×a) + |c|²(a×b)) / (2 a·(b×c)).
    const Vec3 offset = (a.squaredNorm() * b.cross(c) + b.squaredNorm() * c.cross(a) +
                         c.squaredNorm() * a.cross(b)) /
                        (2 * det);
    const double ratio = offset.norm() / shortest;
    q.max_radius_edge_ratio = std::max(q.max_radius_edge_ratio, ratio);
    ratio_sum += ratio;
  }
  q.mean_radius_edge_ratio = ratio_sum / double(mesh.tets.rows());
  return q;
}

}  // namespace flsh
