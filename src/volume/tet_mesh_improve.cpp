// Quality improvement of a tet mesh with a fixed surface (improveTetMeshQuality in
// include/flsh/volume/tet_mesh.h): flips (2–3 face flips, edge removal by Klincsek's dynamic
// programming over the edge's ring, after Shewchuk, "Two discrete optimization algorithms for
// the topological improvement of tetrahedral meshes") and interior-node moves (centroid, then
// ascent on the worst dihedral sine with the min-norm direction of the active gradients, after
// Freitag & Ollivier-Gooch). Every accepted operation raises the worst quality among the tets it
// replaces or moves, so the mesh's worst quality is monotone and nothing inverts.
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <string>
#include <tuple>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/volume/tet_mesh.h"
#include "volume/tet_mesh_internal.h"

namespace flsh {
namespace {

using Tet = std::array<int, 4>;

constexpr int kEdges[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};
// For edge e = kEdges[e], the two other local vertices (the faces opposite them share the edge).
constexpr int kEdgeOthers[6][2] = {{2, 3}, {1, 3}, {1, 2}, {0, 3}, {0, 2}, {0, 1}};
// The face opposite each local vertex, outward (counter-clockwise seen from outside the tet).
constexpr int kFaces[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};

// Tets whose quality is below this are the ones attacked: a dihedral angle under 20° or over 160°.
const double kTargetSine = std::sin(20.0 * M_PI / 180.0);
// An operation must raise the worst affected quality by at least this much (absolute sine):
// ends the rounds and keeps rounding noise from being accepted as improvement.
constexpr double kMinGain = 1e-6;
// Largest ring of an edge removal (Klincsek's table is O(m³); bigger rings almost never succeed).
constexpr int kMaxRing = 9;
constexpr int kMaxRounds = 8;
// Ascent steps per node move, line-search halvings per step, and the first step as a fraction of
// the node's mean incident edge length.
constexpr int kAscentSteps = 8;
constexpr int kLineSearchHalvings = 10;
constexpr double kFirstStepFraction = 0.2;
// Sines within this of the worst one at a node count as active in the ascent direction.
constexpr double kActiveBand = 0.02;
// At most this many active sines (the smallest) enter the min-norm direction.
constexpr int kMaxActive = 6;
// A new or moved tet may not have a radius–edge ratio above this or above the worst ratio among
// the tets it replaces, whichever is larger: flips and moves otherwise trade slivers for tets
// with one short edge (needles), which raise the mesh's worst ratio (2.5 is Mesh_3's bound on its
// cells; the flipped Delaunay input stays under it).
constexpr double kRadiusEdgeLimit = 2.5;

Vec3 rowOf(const MatX3& X, int i) { return X.row(i).transpose(); }

// The six dihedral sines of tet (x0, x1, x2, x3) in kEdges order, signed by the volume:
// sin θ_ij = 6 V ℓ_ij / (|n_k| |n_l|) with n_k the area vector (× 2) of the face opposite k.
std::array<double, 6> dihedralSines(const Vec3& x0, const Vec3& x1, const Vec3& x2,
                                    const Vec3& x3) {
  const Vec3 x[4] = {x0, x1, x2, x3};
  const double det = (x1 - x0).dot((x2 - x0).cross(x3 - x0));
  const double normal[4] = {(x2 - x1).cross(x3 - x1).norm(), (x2 - x0).cross(x3 - x0).norm(),
                            (x1 - x0).cross(x3 - x0).norm(), (x1 - x0).cross(x2 - x0).norm()};
  std::array<double, 6> sines;
  for (int e = 0; e < 6; ++e) {
    const double denominator = normal[kEdgeOthers[e][0]] * normal[kEdgeOthers[e][1]];
    const double length = (x[kEdges[e][0]] - x[kEdges[e][1]]).norm();
    // A face of zero area makes the tet flat: quality 0 (or negative if it is inverted).
    sines[size_t(e)] = denominator > 0 ? det * length / denominator : std::min(det, 0.0);
  }
  return sines;
}

double minSine(const Vec3& x0, const Vec3& x1, const Vec3& x2, const Vec3& x3) {
  const auto s = dihedralSines(x0, x1, x2, x3);
  return *std::min_element(s.begin(), s.end());
}

// Circumradius over shortest edge; infinite for a flat tet.
double radiusEdgeRatio(const Vec3& x0, const Vec3& x1, const Vec3& x2, const Vec3& x3) {
  const Vec3 a = x1 - x0, b = x2 - x0, c = x3 - x0;
  const double det = a.dot(b.cross(c));
  if (det == 0) return std::numeric_limits<double>::infinity();
  const Vec3 offset =
      (a.squaredNorm() * b.cross(c) + b.squaredNorm() * c.cross(a) + c.squaredNorm() * a.cross(b)) /
      (2 * det);
  const double shortest = std::sqrt(
      std::min({a.squaredNorm(), b.squaredNorm(), c.squaredNorm(), (x2 - x1).squaredNorm(),
                (x3 - x1).squaredNorm(), (x3 - x2).squaredNorm()}));
  return offset.norm() / shortest;
}

// The quality of a tet that replaces or moves others: its smallest dihedral sine, or −∞ when its
// radius–edge ratio exceeds `ratio_limit`.
double admissibleQuality(const Vec3& x0, const Vec3& x1, const Vec3& x2, const Vec3& x3,
                         double ratio_limit) {
  const double quality = minSine(x0, x1, x2, x3);
  if (quality <= 0 || radiusEdgeRatio(x0, x1, x2, x3) > ratio_limit)
    return -std::numeric_limits<double>::infinity();
  return quality;
}

// Whether `order` is an odd permutation of `stored` (then it lists the tet inverted).
bool oddPermutation(const Tet& stored, const Tet& order) {
  int position[4];
  for (int k = 0; k < 4; ++k)
    position[k] = int(std::find(stored.begin(), stored.end(), order[size_t(k)]) - stored.begin());
  int inversions = 0;
  for (int i = 0; i < 4; ++i)
    for (int j = i + 1; j < 4; ++j) inversions += position[i] > position[j];
  return inversions % 2 == 1;
}

// A replacement of some tets by others, evaluated but not yet applied.
struct Candidate {
  std::vector<int> removed;
  std::vector<Tet> added;
  double old_min = 0, new_min = -std::numeric_limits<double>::infinity();
  bool is_edge_removal = false;
  bool improves() const { return !added.empty() && new_min > old_min + kMinGain; }
};

class TetImprover {
 public:
  explicit TetImprover(TetMesh& mesh) : mesh_(mesh) {
    const int n = mesh.numNodes();
    tets_.resize(size_t(mesh.numTets()));
    node_tets_.resize(size_t(n));
    for (int t = 0; t < mesh.numTets(); ++t) {
      for (int k = 0; k < 4; ++k) tets_[size_t(t)][size_t(k)] = mesh.tets(t, k);
      for (int k = 0; k < 4; ++k) node_tets_[size_t(mesh.tets(t, k))].push_back(t);
      quality_.push_back(tetQuality(tets_[size_t(t)]));
      alive_.push_back(1);
    }
    // Nodes that may move: interior by index and on no boundary face.
    movable_.assign(size_t(n), 0);
    for (int i = mesh.num_surface_nodes; i < n; ++i) movable_[size_t(i)] = 1;
    const MatX3i boundary = boundaryFaces(mesh.tets);
    for (int f = 0; f < boundary.rows(); ++f)
      for (int k = 0; k < 3; ++k) movable_[size_t(boundary(f, k))] = 0;
  }

  double worstQuality() const {
    double worst = std::numeric_limits<double>::infinity();
    for (size_t t = 0; t < tets_.size(); ++t)
      if (alive_[t]) worst = std::min(worst, quality_[t]);
    return worst;
  }

  // One pass of flips over the tets below the target, worst first; returns how many flips.
  int flipPass(TetMeshImprovement& stats) {
    std::vector<std::pair<double, int>> bad;
    for (size_t t = 0; t < tets_.size(); ++t)
      if (alive_[t] && quality_[t] < kTargetSine) bad.emplace_back(quality_[t], int(t));
    std::sort(bad.begin(), bad.end());
    int flips = 0;
    for (const auto& [quality, t] : bad) {
      if (!alive_[size_t(t)]) continue;
      Candidate best;
      const Tet tet = tets_[size_t(t)];
      for (const auto& e : kEdges) {
        Candidate c = edgeRemoval(tet[size_t(e[0])], tet[size_t(e[1])]);
        if (c.improves() && c.new_min > best.new_min) best = std::move(c);
      }
      for (int f = 0; f < 4; ++f) {
        Candidate c = faceFlip(t, f);
        if (c.improves() && c.new_min > best.new_min) best = std::move(c);
      }
      if (!best.improves()) continue;
      apply(best);
      ++flips;
      ++(best.is_edge_removal ? stats.edge_removals : stats.face_flips);
    }
    return flips;
  }

  // One pass of moves over the movable nodes of tets below the target, worst first.
  int movePass(TetMeshImprovement& stats) {
    std::vector<double> worst_at(mesh_.nodes.rows(), std::numeric_limits<double>::infinity());
    for (size_t t = 0; t < tets_.size(); ++t)
      if (alive_[t] && quality_[t] < kTargetSine)
        for (const int v : tets_[t])
          worst_at[size_t(v)] = std::min(worst_at[size_t(v)], quality_[t]);
    std::vector<std::pair<double, int>> nodes;
    for (int v = 0; v < int(worst_at.size()); ++v)
      if (movable_[size_t(v)] && worst_at[size_t(v)] < kTargetSine)
        nodes.emplace_back(worst_at[size_t(v)], v);
    std::sort(nodes.begin(), nodes.end());
    int moves = 0;
    for (const auto& node : nodes) moves += moveNode(node.second);
    stats.node_moves += moves;
    return moves;
  }

  // Writes the live tets back in canonical order.
  void finish() {
    std::vector<Tet> live;
    for (size_t t = 0; t < tets_.size(); ++t)
      if (alive_[t]) live.push_back(tets_[t]);
    mesh_.tets = canonicalTets(std::move(live));
  }

 private:
  Vec3 node(int i) const { return rowOf(mesh_.nodes, i); }

  double tetQuality(const Tet& t) const {
    return minSine(node(t[0]), node(t[1]), node(t[2]), node(t[3]));
  }

  // Live tets containing both a and b.
  std::vector<int> tetsWithEdge(int a, int b) const {
    const auto& shorter = node_tets_[size_t(a)].size() <= node_tets_[size_t(b)].size()
                              ? node_tets_[size_t(a)]
                              : node_tets_[size_t(b)];
    std::vector<int> out;
    for (const int t : shorter) {
      const Tet& tet = tets_[size_t(t)];
      if (std::find(tet.begin(), tet.end(), a) != tet.end() &&
          std::find(tet.begin(), tet.end(), b) != tet.end())
        out.push_back(t);
    }
    return out;
  }

  // Removing interior edge ab: its ring r_0..r_{m−1} (oriented so that (a, b, r_i, r_{i+1}) is
  // positive) is triangulated by the triangulation maximizing the worst of the new tets
  // (a, r_i, r_k, r_j) and (b, r_i, r_j, r_k), i < k < j. No candidate for a boundary edge (its
  // ring is open) or a ring larger than kMaxRing.
  Candidate edgeRemoval(int a, int b) const {
    Candidate c;
    c.is_edge_removal = true;
    const std::vector<int> around = tetsWithEdge(a, b);
    const int m = int(around.size());
    if (m < 3 || m > kMaxRing) return c;
    std::vector<std::pair<int, int>> next;  // ring vertex → its successor
    for (const int t : around) {
      const Tet& tet = tets_[size_t(t)];
      int others[2], n = 0;
      for (const int v : tet)
        if (v != a && v != b) others[n++] = v;
      if (oddPermutation(tet, {a, b, others[0], others[1]})) std::swap(others[0], others[1]);
      next.emplace_back(others[0], others[1]);
    }
    std::sort(next.begin(), next.end());
    for (size_t i = 1; i < next.size(); ++i)
      if (next[i].first == next[i - 1].first) return c;  // not a simple ring
    std::vector<int> ring{next.front().first};
    for (int step = 0; step < m; ++step) {
      const auto it = std::lower_bound(next.begin(), next.end(), std::make_pair(ring.back(), -1));
      if (it == next.end() || it->first != ring.back()) return c;  // open ring: a boundary edge
      ring.push_back(it->second);
    }
    if (ring.back() != ring.front()) return c;
    ring.pop_back();

    Vec3 x[kMaxRing];
    for (int i = 0; i < m; ++i) x[i] = node(ring[size_t(i)]);
    const double limit = ratioLimit(around);
    const Vec3 xa = node(a), xb = node(b);
    // best[i][j]: the best worst quality of a triangulation of ring polygon i..j; split[i][j]
    // the apex k of the triangle on chord ij.
    double best[kMaxRing][kMaxRing];
    int split[kMaxRing][kMaxRing];
    for (int i = 0; i + 1 < m; ++i) best[i][i + 1] = std::numeric_limits<double>::infinity();
    for (int gap = 2; gap < m; ++gap) {
      for (int i = 0; i + gap < m; ++i) {
        const int j = i + gap;
        best[i][j] = -std::numeric_limits<double>::infinity();
        split[i][j] = -1;
        for (int k = i + 1; k < j; ++k) {
          const double value =
              std::min({best[i][k], best[k][j], admissibleQuality(xa, x[i], x[k], x[j], limit),
                        admissibleQuality(xb, x[i], x[j], x[k], limit)});
          if (value > best[i][j]) {
            best[i][j] = value;
            split[i][j] = k;
          }
        }
      }
    }
    c.removed = around;
    c.old_min = std::numeric_limits<double>::infinity();
    for (const int t : around) c.old_min = std::min(c.old_min, quality_[size_t(t)]);
    c.new_min = best[0][m - 1];
    if (!(c.new_min > c.old_min + kMinGain)) return c;
    std::vector<std::pair<int, int>> chords{{0, m - 1}};
    while (!chords.empty()) {
      const auto [i, j] = chords.back();
      chords.pop_back();
      if (j - i < 2) continue;
      const int k = split[i][j];
      const int ri = ring[size_t(i)], rk = ring[size_t(k)], rj = ring[size_t(j)];
      c.added.push_back({a, ri, rk, rj});
      c.added.push_back({b, ri, rj, rk});
      chords.emplace_back(i, k);
      chords.emplace_back(k, j);
    }
    return c;
  }

  // 2–3 flip of the face of tet t opposite its local vertex f: the face's two tets (apexes d, e)
  // become three around the new edge de. No candidate for a boundary face.
  Candidate faceFlip(int t, int f) const {
    Candidate c;
    const Tet& tet = tets_[size_t(t)];
    const int p = tet[size_t(kFaces[f][0])], q = tet[size_t(kFaces[f][1])],
              r = tet[size_t(kFaces[f][2])], d = tet[size_t(f)];
    int other = -1;
    for (const int s : tetsWithEdge(p, q)) {
      const Tet& u = tets_[size_t(s)];
      if (s != t && std::find(u.begin(), u.end(), r) != u.end()) other = s;
    }
    if (other < 0) return c;
    int e = -1;
    for (const int v : tets_[size_t(other)])
      if (v != p && v != q && v != r) e = v;
    // (p, q, r) is outward of t (counter-clockwise seen from e), so (d, e, p, q) etc. are positive.
    const Tet added[3] = {{d, e, p, q}, {d, e, q, r}, {d, e, r, p}};
    c.old_min = std::min(quality_[size_t(t)], quality_[size_t(other)]);
    c.new_min = std::numeric_limits<double>::infinity();
    const double limit = ratioLimit({t, other});
    for (const Tet& n : added)
      c.new_min = std::min(
          c.new_min, admissibleQuality(node(n[0]), node(n[1]), node(n[2]), node(n[3]), limit));
    if (!(c.new_min > c.old_min + kMinGain)) return c;
    c.removed = {t, other};
    c.added.assign(std::begin(added), std::end(added));
    return c;
  }

  void apply(const Candidate& c) {
    for (const int t : c.removed) {
      alive_[size_t(t)] = 0;
      for (const int v : tets_[size_t(t)]) {
        auto& list = node_tets_[size_t(v)];
        list.erase(std::find(list.begin(), list.end(), t));
      }
    }
    for (const Tet& tet : c.added) {
      const int t = int(tets_.size());
      tets_.push_back(tet);
      alive_.push_back(1);
      quality_.push_back(tetQuality(tet));
      for (const int v : tet) node_tets_[size_t(v)].push_back(t);
    }
  }

  // The radius–edge bound for tets that replace or move `tets`.
  double ratioLimit(const std::vector<int>& tets) const {
    double limit = kRadiusEdgeLimit;
    for (const int t : tets) {
      const Tet& tet = tets_[size_t(t)];
      limit =
          std::max(limit, radiusEdgeRatio(node(tet[0]), node(tet[1]), node(tet[2]), node(tet[3])));
    }
    return limit;
  }

  // Worst quality of the tets around node v with v placed at x (−∞ if one of them has a
  // radius–edge ratio above `ratio_limit`).
  double worstAround(int v, const Vec3& x, double ratio_limit) const {
    double worst = std::numeric_limits<double>::infinity();
    for (const int t : node_tets_[size_t(v)]) {
      Vec3 p[4];
      for (int k = 0; k < 4; ++k) {
        const int i = tets_[size_t(t)][size_t(k)];
        p[k] = i == v ? x : node(i);
      }
      worst = std::min(worst, admissibleQuality(p[0], p[1], p[2], p[3], ratio_limit));
    }
    return worst;
  }

  // Moves node v to the first of its candidate positions that raise its worst incident quality
  // (the neighbours' centroid, then ascent steps); returns whether it moved.
  bool moveNode(int v) {
    const Vec3 start = node(v);
    Vec3 x = start;
    const double limit = ratioLimit(node_tets_[size_t(v)]);
    double worst = worstAround(v, x, limit);
    // Neighbours' centroid and mean incident edge length.
    std::vector<int> neighbours;
    for (const int t : node_tets_[size_t(v)])
      for (const int i : tets_[size_t(t)])
        if (i != v) neighbours.push_back(i);
    std::sort(neighbours.begin(), neighbours.end());
    neighbours.erase(std::unique(neighbours.begin(), neighbours.end()), neighbours.end());
    Vec3 centroid = Vec3::Zero();
    double mean_edge = 0;
    for (const int i : neighbours) {
      centroid += node(i);
      mean_edge += (node(i) - start).norm();
    }
    centroid /= double(neighbours.size());
    mean_edge /= double(neighbours.size());
    const double centroid_worst = worstAround(v, centroid, limit);
    if (centroid_worst > worst + kMinGain) {
      x = centroid;
      worst = centroid_worst;
    }
    for (int step = 0; step < kAscentSteps; ++step) {
      Vec3 direction;
      if (!ascentDirection(v, x, mean_edge, &direction)) break;
      double length = kFirstStepFraction * mean_edge;
      bool moved = false;
      for (int halving = 0; halving < kLineSearchHalvings && !moved; ++halving, length /= 2) {
        const Vec3 trial = x + length * direction;
        const double trial_worst = worstAround(v, trial, limit);
        if (trial_worst > worst + kMinGain) {
          x = trial;
          worst = trial_worst;
          moved = true;
        }
      }
      if (!moved) break;
    }
    if (x == start) return false;
    mesh_.nodes.row(v) = x.transpose();
    for (const int t : node_tets_[size_t(v)]) quality_[size_t(t)] = tetQuality(tets_[size_t(t)]);
    return true;
  }

  // Unit direction that raises every active dihedral sine at node v placed at x (the min-norm
  // point of the convex hull of their gradients, Freitag's nonsmooth ascent); false at a
  // stationary point.
  bool ascentDirection(int v, const Vec3& x, double mean_edge, Vec3* direction) const {
    struct Sine {
      double value;
      int tet, edge;
    };
    std::vector<Sine> sines;
    for (const int t : node_tets_[size_t(v)]) {
      const auto s = sinesAt(t, v, x);
      for (int e = 0; e < 6; ++e) sines.push_back({s[size_t(e)], t, e});
    }
    std::sort(sines.begin(), sines.end(), [](const Sine& p, const Sine& q) {
      return std::tie(p.value, p.tet, p.edge) < std::tie(q.value, q.tet, q.edge);
    });
    std::vector<Vec3> gradients;
    const double h = 1e-6 * mean_edge;
    for (const Sine& s : sines) {
      if (s.value > sines.front().value + kActiveBand || int(gradients.size()) == kMaxActive) break;
      Vec3 g;
      for (int c = 0; c < 3; ++c) {
        Vec3 plus = x, minus = x;
        plus[c] += h;
        minus[c] -= h;
        g[c] =
            (sinesAt(s.tet, v, plus)[size_t(s.edge)] - sinesAt(s.tet, v, minus)[size_t(s.edge)]) /
            (2 * h);
      }
      gradients.push_back(g);
    }
    // A vanishing direction: no move raises every active sine to first order (stationary).
    const Vec3 d = minNormInHull(gradients);
    const double norm = d.norm();
    if (!(norm * mean_edge > 1e-9)) return false;
    for (const Vec3& g : gradients)
      if (g.dot(d) < 0.5 * norm * norm) return false;  // the origin is (nearly) in the hull
    *direction = d / norm;
    return true;
  }

  std::array<double, 6> sinesAt(int t, int v, const Vec3& x) const {
    Vec3 p[4];
    for (int k = 0; k < 4; ++k) {
      const int i = tets_[size_t(t)][size_t(k)];
      p[k] = i == v ? x : node(i);
    }
    return dihedralSines(p[0], p[1], p[2], p[3]);
  }

  // The point of smallest norm in the convex hull of up to kMaxActive 3-vectors: the smallest
  // among the affine projections of the origin onto subsets of 1–3 of them that land inside
  // their simplex (the optimum lies in the relative interior of one such face).
  static Vec3 minNormInHull(const std::vector<Vec3>& g) {
    const int n = int(g.size());
    Vec3 best = g[0];
    const auto consider = [&](const Vec3& p) {
      if (p.squaredNorm() < best.squaredNorm()) best = p;
    };
    for (int i = 0; i < n; ++i) consider(g[size_t(i)]);
    for (int i = 0; i < n; ++i)
      for (int j = i + 1; j < n; ++j) {
        const Vec3 e = g[size_t(j)] - g[size_t(i)];
        if (e.squaredNorm() == 0) continue;
        const double s = -g[size_t(i)].dot(e) / e.squaredNorm();
        if (s > 0 && s < 1) consider(g[size_t(i)] + s * e);
      }
    for (int i = 0; i < n; ++i)
      for (int j = i + 1; j < n; ++j)
        for (int k = j + 1; k < n; ++k) {
          const Vec3 e1 = g[size_t(j)] - g[size_t(i)], e2 = g[size_t(k)] - g[size_t(i)];
          Eigen::Matrix2d A;
          A << e1.dot(e1), e1.dot(e2), e1.dot(e2), e2.dot(e2);
          const Eigen::Vector2d rhs(-g[size_t(i)].dot(e1), -g[size_t(i)].dot(e2));
          if (std::abs(A.determinant()) <= 1e-14 * A.trace() * A.trace()) continue;
          const Eigen::Vector2d s = A.inverse() * rhs;
          if (s[0] > 0 && s[1] > 0 && s[0] + s[1] < 1)
            consider(g[size_t(i)] + s[0] * e1 + s[1] * e2);
        }
    return best;
  }

  TetMesh& mesh_;
  std::vector<Tet> tets_;  // live and dead; dead ones are skipped
  std::vector<char> alive_;
  std::vector<double> quality_;
  std::vector<std::vector<int>> node_tets_;  // live tets of each node
  std::vector<char> movable_;
};

}  // namespace

TetMeshImprovement improveTetMeshQuality(TetMesh& mesh) {
  const std::string where = "improveTetMeshQuality: ";
  const int n = mesh.numNodes();
  if (!mesh.nodes.allFinite()) throw InputError(where + "mesh.nodes contain NaN or Inf");
  if (mesh.num_surface_nodes < 0 || mesh.num_surface_nodes > n)
    throw InputError(where + "mesh.num_surface_nodes = " + std::to_string(mesh.num_surface_nodes) +
                     " is outside [0, " + std::to_string(n) + "]");
  for (int t = 0; t < mesh.numTets(); ++t)
    for (int k = 0; k < 4; ++k) {
      const int i = mesh.tets(t, k);
      if (i < 0 || i >= n)
        throw InputError(where + "tet " + std::to_string(t) + " has node index " +
                         std::to_string(i) + " outside [0, " + std::to_string(n) + ")");
      for (int l = 0; l < k; ++l)
        if (mesh.tets(t, l) == i)
          throw InputError(where + "tet " + std::to_string(t) + " repeats node " +
                           std::to_string(i));
    }
  const VecX volumes = tetVolumes(mesh);
  for (int t = 0; t < volumes.size(); ++t)
    if (!(volumes[t] > 0))
      throw InputError(where + "tet " + std::to_string(t) + " has volume " +
                       std::to_string(volumes[t]) + " m³; expected > 0");

  TetMeshImprovement stats;
  TetImprover improver(mesh);
  stats.min_sine_before = improver.worstQuality();
  for (int round = 0; round < kMaxRounds; ++round) {
    ++stats.rounds;
    const int changes = improver.flipPass(stats) + improver.movePass(stats);
    if (changes == 0) break;
  }
  improver.finish();
  stats.min_sine_after = improver.worstQuality();
  return stats;
}

}  // namespace flsh
