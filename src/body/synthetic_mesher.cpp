#include "body/synthetic_mesher.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <unordered_map>
#include <vector>

#include "flsh/core/error.h"

namespace flsh::synthetic {

namespace {

using Tri = std::array<int, 3>;
constexpr double kPi = 3.14159265358979323846;

Vec3 centralGradient(const ImplicitSurface& s, const Vec3& p, double eps) {
  Vec3 g;
  for (int c = 0; c < 3; ++c) {
    Vec3 a = p, b = p;
    a[c] += eps;
    b[c] -= eps;
    g[c] = (s.value(a) - s.value(b)) / (2 * eps);
  }
  return g;
}

// ---------------------------------------------------------------------------------------
// Marching tetrahedra

struct Soup {
  std::vector<Vec3> points;
  std::vector<Tri> faces;
};

// Parity of a permutation of {0,1,2,3} (true = odd).
bool isOdd(const std::array<int, 4>& perm) {
  int inversions = 0;
  for (int i = 0; i < 4; ++i)
    for (int j = i + 1; j < 4; ++j) inversions += perm[i] > perm[j];
  return inversions % 2 == 1;
}

// The 6 tetrahedra of the Kuhn split of a cube (corner c = dx + 2 dy + 4 dz), each listed in
// positive orientation. Neighbouring cubes split their shared faces along the same diagonal.
std::array<std::array<int, 4>, 6> kuhnTetrahedra() {
  std::array<std::array<int, 4>, 6> tets;
  const int axes[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  auto corner = [](int c) { return Vec3(c & 1, (c >> 1) & 1, (c >> 2) & 1); };
  for (int t = 0; t < 6; ++t) {
    const int c1 = 1 << axes[t][0];
    const int c2 = c1 | (1 << axes[t][1]);
    std::array<int, 4> tet = {0, c1, c2, 7};
    const Vec3 p0 = corner(tet[0]);
    const double det = (corner(tet[1]) - p0).dot((corner(tet[2]) - p0).cross(corner(tet[3]) - p0));
    if (det < 0) std::swap(tet[2], tet[3]);
    tets[t] = tet;
  }
  return tets;
}

Soup marchingTetrahedra(const ImplicitSurface& s, double h) {
  const Vec3 extent = s.box_max - s.box_min;
  const int nx = int(std::ceil(extent.x() / h)) + 1;
  const int ny = int(std::ceil(extent.y() / h)) + 1;
  const int nz = int(std::ceil(extent.z() / h)) + 1;
  // Centre the grid on the box so a mirror-symmetric surface meets a mirror-symmetric grid.
  const Vec3 centre = 0.5 * (s.box_min + s.box_max);
  const Vec3 origin = centre - 0.5 * h * Vec3(nx - 1, ny - 1, nz - 1);
  const long num_nodes = long(nx) * ny * nz;
  auto node = [&](int i, int j, int k) { return long(i) + long(nx) * (long(j) + long(ny) * k); };
  auto nodePoint = [&](int i, int j, int k) { return Vec3(origin + h * Vec3(i, j, k)); };

  std::vector<double> values(num_nodes, std::numeric_limits<double>::quiet_NaN());
  // Blocks of B³ cells: skip a block whose centre value proves that no surface passes through
  // it (Lipschitz bound 2 with a safety cell), so only a shell around the surface is sampled.
  constexpr int B = 4;
  std::vector<std::array<int, 3>> active_blocks;
  for (int bk = 0; bk * B < nz - 1; ++bk)
    for (int bj = 0; bj * B < ny - 1; ++bj)
      for (int bi = 0; bi * B < nx - 1; ++bi) {
        const int ci = std::min(B, nx - 1 - bi * B), cj = std::min(B, ny - 1 - bj * B),
                  ck = std::min(B, nz - 1 - bk * B);
        const Vec3 block_centre =
            origin + h * Vec3(bi * B + 0.5 * ci, bj * B + 0.5 * cj, bk * B + 0.5 * ck);
        const double half_diagonal = 0.5 * h * std::sqrt(double(ci * ci + cj * cj + ck * ck));
        if (std::abs(s.value(block_centre)) > 2.0 * half_diagonal + h) continue;
        active_blocks.push_back({bi, bj, bk});
        for (int k = bk * B; k <= bk * B + ck; ++k)
          for (int j = bj * B; j <= bj * B + cj; ++j)
            for (int i = bi * B; i <= bi * B + ci; ++i) {
              double& v = values[node(i, j, k)];
              if (std::isnan(v)) {
                // Keep |value| ≥ h/20 (sign kept): the isosurface then stays ≥ 3 % of an
                // edge away from every node and marching tetrahedra makes no micro-faces.
                v = s.value(nodePoint(i, j, k));
                if (std::abs(v) < 0.05 * h) v = v < 0 ? -0.05 * h : 0.05 * h;
              }
            }
      }

  const auto tets = kuhnTetrahedra();
  Soup soup;
  std::unordered_map<std::uint64_t, int> edge_point;
  auto inside = [&](long n) { return values[n] < 0.0; };  // 0 counts as outside
  auto edgePoint = [&](long n_in, long n_out) {
    const std::uint64_t key = std::uint64_t(std::min(n_in, n_out)) * std::uint64_t(num_nodes) +
                              std::uint64_t(std::max(n_in, n_out));
    auto [it, inserted] = edge_point.emplace(key, int(soup.points.size()));
    if (inserted) {
      const double f_in = values[n_in], f_out = values[n_out];
      const double t = f_in / (f_in - f_out);
      auto point = [&](long n) {
        const long i = n % nx, j = (n / nx) % ny, k = n / (long(nx) * ny);
        return Vec3(origin + h * Vec3(double(i), double(j), double(k)));
      };
      soup.points.push_back((1 - t) * point(n_in) + t * point(n_out));
    }
    return it->second;
  };

  for (const auto& blk : active_blocks) {
    const int i0 = blk[0] * B, j0 = blk[1] * B, k0 = blk[2] * B;
    const int i1 = std::min(i0 + B, nx - 1), j1 = std::min(j0 + B, ny - 1),
              k1 = std::min(k0 + B, nz - 1);
    for (int k = k0; k < k1; ++k)
      for (int j = j0; j < j1; ++j)
        for (int i = i0; i < i1; ++i) {
          std::array<long, 8> corner;
          int num_inside = 0;
          for (int c = 0; c < 8; ++c) {
            corner[c] = node(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1));
            num_inside += inside(corner[c]);
          }
          if (num_inside == 0 || num_inside == 8) continue;
          for (const auto& tet : tets) {
            std::array<long, 4> n;
            int mask = 0;
            for (int q = 0; q < 4; ++q) {
              n[q] = corner[tet[q]];
              mask |= int(inside(n[q])) << q;
            }
            const int count = __builtin_popcount(unsigned(mask));
            if (count == 0 || count == 4) continue;
            if (count == 1 || count == 3) {
              // Lone vertex L (the only inside one, or the only outside one).
              int lone = 0;
              for (int q = 0; q < 4; ++q)
                if (((mask >> q) & 1) == (count == 1 ? 1 : 0)) lone = q;
              std::array<int, 4> perm = {lone, 0, 0, 0};
              int m = 1;
              for (int q = 0; q < 4; ++q)
                if (q != lone) perm[m++] = q;
              if (isOdd(perm)) std::swap(perm[2], perm[3]);
              // With (L, A, B, C) positive, triangle (LA, LB, LC) faces away from L.
              const long L = n[perm[0]];
              const int ea = count == 1 ? edgePoint(L, n[perm[1]]) : edgePoint(n[perm[1]], L);
              const int eb = count == 1 ? edgePoint(L, n[perm[2]]) : edgePoint(n[perm[2]], L);
              const int ec = count == 1 ? edgePoint(L, n[perm[3]]) : edgePoint(n[perm[3]], L);
              if (count == 1)
                soup.faces.push_back({ea, eb, ec});
              else
                soup.faces.push_back({ea, ec, eb});
            } else {
              std::array<int, 4> perm;
              int in_count = 0, out_count = 2;
              for (int q = 0; q < 4; ++q) {
                if ((mask >> q) & 1)
                  perm[in_count++] = q;
                else
                  perm[out_count++] = q;
              }
              if (isOdd(perm)) std::swap(perm[2], perm[3]);
              const long a = n[perm[0]], b = n[perm[1]], c = n[perm[2]], d = n[perm[3]];
              const int ac = edgePoint(a, c), ad = edgePoint(a, d), bd = edgePoint(b, d),
                        bc = edgePoint(b, c);
              soup.faces.push_back({ac, ad, bd});
              soup.faces.push_back({ac, bd, bc});
            }
          }
        }
  }
  return soup;
}

// Keeps the largest connected component (by face count) and drops unreferenced points.
Soup largestComponent(const Soup& soup) {
  const int nv = int(soup.points.size());
  std::vector<int> parent(nv);
  for (int i = 0; i < nv; ++i) parent[i] = i;
  std::function<int(int)> find = [&](int x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  for (const Tri& t : soup.faces)
    for (int e = 1; e < 3; ++e) {
      const int ra = find(t[0]), rb = find(t[e]);
      if (ra != rb) parent[std::max(ra, rb)] = std::min(ra, rb);
    }
  std::vector<int> face_count(nv, 0);
  for (const Tri& t : soup.faces) ++face_count[find(t[0])];
  const int best = int(std::max_element(face_count.begin(), face_count.end()) - face_count.begin());
  Soup out;
  std::vector<int> remap(nv, -1);
  for (const Tri& t : soup.faces) {
    if (find(t[0]) != best) continue;
    Tri r;
    for (int c = 0; c < 3; ++c) {
      if (remap[t[c]] < 0) {
        remap[t[c]] = int(out.points.size());
        out.points.push_back(soup.points[t[c]]);
      }
      r[c] = remap[t[c]];
    }
    out.faces.push_back(r);
  }
  return out;
}

// ---------------------------------------------------------------------------------------
// Editable triangle mesh: positions, faces and, per vertex, its incident faces.

struct WorkMesh {
  std::vector<Vec3> p;
  std::vector<Tri> f;
  std::vector<char> face_alive, vertex_alive;
  std::vector<std::vector<int>> vf;

  explicit WorkMesh(const Soup& soup) : p(soup.points), f(soup.faces) {
    face_alive.assign(f.size(), 1);
    vertex_alive.assign(p.size(), 1);
    vf.assign(p.size(), {});
    for (int fi = 0; fi < int(f.size()); ++fi)
      for (int c : f[fi]) vf[c].push_back(fi);
  }
  Vec3 areaNormal(const Tri& t) const { return (p[t[1]] - p[t[0]]).cross(p[t[2]] - p[t[0]]); }
  void neighbours(int v, std::vector<int>& out) const {
    out.clear();
    for (int fi : vf[v])
      for (int c : f[fi])
        if (c != v) out.push_back(c);
    std::sort(out.begin(), out.end());
    out.erase(std::unique(out.begin(), out.end()), out.end());
  }
  bool adjacent(int a, int b) const {
    for (int fi : vf[a])
      for (int c : f[fi])
        if (c == b) return true;
    return false;
  }
  static void eraseValue(std::vector<int>& list, int value) {
    list.erase(std::find(list.begin(), list.end(), value));
  }
};

// Triangle shape quality 4√3·area / Σ edge² ∈ [0, 1] (1 = equilateral, 0 = degenerate).
double shapeQuality(const Vec3& a, const Vec3& b, const Vec3& c) {
  const double edges = (b - a).squaredNorm() + (c - b).squaredNorm() + (a - c).squaredNorm();
  return edges > 0 ? 2.0 * std::sqrt(3.0) * (b - a).cross(c - a).norm() / edges : 0.0;
}

// Smallest quality a collapse, flip or move may create, unless the faces it replaces were
// already worse (the slivers of marching tetrahedra).
constexpr double kMinQuality = 0.1;

int thirdVertex(const Tri& t, int a, int b) {
  for (int c : t)
    if (c != a && c != b) return c;
  return -1;
}

bool contains(const Tri& t, int v) { return t[0] == v || t[1] == v || t[2] == v; }

// Thresholds of the geometric checks of a collapse; relaxed when decimation gets stuck.
struct CollapseStrictness {
  double min_cos_old;  // new face normal vs the same face before
  double min_cos_avg;  // new face normal vs the mean normal of the edge's neighbourhood
};

// Collapses edge (a, b) into a at `target`, if that keeps the mesh a closed manifold (link
// condition), keeps every vertex at valence ≥ 3 and flips no face.
bool tryCollapse(WorkMesh& m, int a, int b, const Vec3& target, const CollapseStrictness& strict,
                 std::vector<int>& na, std::vector<int>& nb) {
  int f1 = -1, f2 = -1;
  for (int fi : m.vf[b]) {
    if (!contains(m.f[fi], a)) continue;
    if (f1 < 0)
      f1 = fi;
    else if (f2 < 0)
      f2 = fi;
    else
      return false;
  }
  if (f2 < 0) return false;
  const int c = thirdVertex(m.f[f1], a, b), d = thirdVertex(m.f[f2], a, b);
  if (c == d) return false;
  if (m.vf[c].size() <= 3 || m.vf[d].size() <= 3) return false;
  m.neighbours(a, na);
  m.neighbours(b, nb);
  int common = 0;
  for (std::size_t i = 0, j = 0; i < na.size() && j < nb.size();) {
    if (na[i] < nb[j]) {
      ++i;
    } else if (nb[j] < na[i]) {
      ++j;
    } else {
      ++common;
      ++i;
      ++j;
    }
  }
  if (common != 2) return false;

  Vec3 mean_normal = Vec3::Zero();
  double worst_quality = 1.0;
  for (int v : {a, b})
    for (int fi : m.vf[v]) {
      const Tri& t = m.f[fi];
      mean_normal += m.areaNormal(t);
      worst_quality = std::min(worst_quality, shapeQuality(m.p[t[0]], m.p[t[1]], m.p[t[2]]));
    }
  const double mean_norm = mean_normal.norm();
  for (int v : {a, b})
    for (int fi : m.vf[v]) {
      if (fi == f1 || fi == f2) continue;
      const Vec3 old_normal = m.areaNormal(m.f[fi]);
      Tri t = m.f[fi];
      std::array<Vec3, 3> q;
      for (int k = 0; k < 3; ++k) q[k] = (t[k] == a || t[k] == b) ? target : m.p[t[k]];
      const Vec3 new_normal = (q[1] - q[0]).cross(q[2] - q[0]);
      const double new_norm = new_normal.norm(), old_norm = old_normal.norm();
      if (!(new_norm > 1e-18)) return false;
      if (shapeQuality(q[0], q[1], q[2]) < std::min(kMinQuality, worst_quality)) return false;
      // A sliver's normal is unreliable: only well-shaped faces must keep their direction.
      const bool reliable = shapeQuality(m.p[t[0]], m.p[t[1]], m.p[t[2]]) > 0.05;
      if (reliable && new_normal.dot(old_normal) < strict.min_cos_old * new_norm * old_norm)
        return false;
      if (mean_norm > 1e-18 &&
          new_normal.dot(mean_normal) < strict.min_cos_avg * new_norm * mean_norm)
        return false;
    }

  m.p[a] = target;
  for (int fi : m.vf[b]) {
    if (fi == f1 || fi == f2) continue;
    for (int& k : m.f[fi])
      if (k == b) k = a;
    m.vf[a].push_back(fi);
  }
  m.face_alive[f1] = m.face_alive[f2] = 0;
  WorkMesh::eraseValue(m.vf[a], f1);
  WorkMesh::eraseValue(m.vf[a], f2);
  WorkMesh::eraseValue(m.vf[c], f1);
  WorkMesh::eraseValue(m.vf[d], f2);
  m.vf[b].clear();
  m.vertex_alive[b] = 0;
  return true;
}

struct CollapseCandidate {
  double cost;
  int a, b;
  bool operator<(const CollapseCandidate& o) const {
    if (cost != o.cost) return cost < o.cost;
    if (a != o.a) return a < o.a;
    return b < o.b;
  }
};

// Shortest-edge-first decimation in passes (cache friendly, unlike one big heap): each pass
// sorts the edges by length relative to the target size and collapses them in that order,
// each vertex at most once per pass, removing at most a quarter of the vertices.
void decimate(WorkMesh& m, const ImplicitSurface& s, int target_vertices) {
  int alive = int(std::count(m.vertex_alive.begin(), m.vertex_alive.end(), 1));
  std::vector<int> touched(m.p.size(), -1);
  const CollapseStrictness levels[] = {{0.5, 0.2}, {0.0, 0.0}, {-0.5, -0.3}};
  std::vector<int> na, nb;
  std::vector<CollapseCandidate> edges;
  int level = 0, pass = 0;
  while (alive > target_vertices && level < 3) {
    edges.clear();
    for (int fi = 0; fi < int(m.f.size()); ++fi) {
      if (!m.face_alive[fi]) continue;
      for (int e = 0; e < 3; ++e) {
        const int a = m.f[fi][e], b = m.f[fi][(e + 1) % 3];
        if (a > b) continue;
        const double rel = s.relative_edge_length(0.5 * (m.p[a] + m.p[b]));
        edges.push_back({(m.p[a] - m.p[b]).squaredNorm() / (rel * rel), a, b});
      }
    }
    std::sort(edges.begin(), edges.end());
    const int budget = std::max(1, std::min(alive - target_vertices, alive / 4));
    int collapsed = 0;
    for (const CollapseCandidate& edge : edges) {
      if (collapsed == budget) break;
      const int a = edge.a, b = edge.b;
      if (touched[a] == pass || touched[b] == pass) continue;
      const Vec3 target = projectOntoSurface(s, 0.5 * (m.p[a] + m.p[b]), 1);
      if (!tryCollapse(m, a, b, target, levels[level], na, nb)) continue;
      touched[a] = touched[b] = pass;
      ++collapsed;
    }
    alive -= collapsed;
    ++pass;
    if (collapsed == 0) ++level;
  }
  if (alive != target_vertices)
    throw Error("synthetic body mesher: edge collapse stopped at " + std::to_string(alive) +
                " vertices, expected " + std::to_string(target_vertices) +
                " (the grid is too coarse for this many vertices)");
}

void compact(WorkMesh& m) {
  std::vector<int> remap(m.p.size(), -1);
  Soup soup;
  for (int v = 0; v < int(m.p.size()); ++v)
    if (m.vertex_alive[v]) {
      remap[v] = int(soup.points.size());
      soup.points.push_back(m.p[v]);
    }
  for (int fi = 0; fi < int(m.f.size()); ++fi)
    if (m.face_alive[fi])
      soup.faces.push_back({remap[m.f[fi][0]], remap[m.f[fi][1]], remap[m.f[fi][2]]});
  m = WorkMesh(soup);
}

double angleAt(const Vec3& apex, const Vec3& u, const Vec3& v) {
  const Vec3 a = u - apex, b = v - apex;
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

double minAngle(const WorkMesh& m, const Tri& t) {
  return std::min({angleAt(m.p[t[0]], m.p[t[1]], m.p[t[2]]),
                   angleAt(m.p[t[1]], m.p[t[2]], m.p[t[0]]),
                   angleAt(m.p[t[2]], m.p[t[0]], m.p[t[1]])});
}

// One sweep of Delaunay flips over flat-enough edges. Returns the number of flips.
int flipPass(WorkMesh& m) {
  int flips = 0;
  for (int fi = 0; fi < int(m.f.size()); ++fi) {
    for (int e = 0; e < 3; ++e) {
      const Tri t = m.f[fi];
      const int a = t[e], b = t[(e + 1) % 3], c = t[(e + 2) % 3];
      int g = -1;
      for (int fj : m.vf[a])
        if (fj != fi && contains(m.f[fj], b)) g = fj;
      if (g < 0) continue;
      const int d = thirdVertex(m.f[g], a, b);
      if (c == d || m.adjacent(c, d)) continue;
      if (m.vf[a].size() <= 3 || m.vf[b].size() <= 3) continue;
      const double opposite = angleAt(m.p[c], m.p[a], m.p[b]) + angleAt(m.p[d], m.p[b], m.p[a]);
      const Tri t1 = {a, d, c}, t2 = {d, b, c};
      const double old_min = std::min(minAngle(m, t), minAngle(m, m.f[g]));
      const double new_min = std::min(minAngle(m, t1), minAngle(m, t2));
      // Delaunay flips, and flips that remove a sliver (also across creases).
      const bool sliver = old_min < 15.0 * kPi / 180.0 && new_min > old_min;
      if (opposite <= kPi + 1e-9 && !sliver) continue;
      const Vec3 area_f = m.areaNormal(t), area_g = m.areaNormal(m.f[g]);
      const Vec3 n1 = m.areaNormal(t1), n2 = m.areaNormal(t2);
      if (!(n1.norm() > 1e-18 && n2.norm() > 1e-18)) continue;
      const Vec3 u1 = n1.normalized(), u2 = n2.normalized();
      // Only where the surface is flat enough that the flip keeps its shape (a sliver's own
      // normal is meaningless, so it is judged by the new faces alone).
      if (!sliver && (area_f.normalized().dot(area_g.normalized()) < 0.8 || u1.dot(u2) < 0.6))
        continue;
      if (sliver && u1.dot(u2) < 0.5) continue;
      // Area-weighted: a degenerate old face has no say in the reference direction.
      const Vec3 reference = area_f + area_g;
      if (u1.dot(reference) <= 0 || u2.dot(reference) <= 0) continue;
      m.f[fi] = t1;
      m.f[g] = t2;
      WorkMesh::eraseValue(m.vf[a], g);
      WorkMesh::eraseValue(m.vf[b], fi);
      m.vf[c].push_back(g);
      m.vf[d].push_back(fi);
      ++flips;
    }
  }
  return flips;
}

// Gauss–Seidel tangential relaxation towards the density-weighted centroid of the one-ring
// (centroidal Voronoi with density 1 / relative_edge_length²), then projection onto the
// surface; a move that would flip or flatten an incident face is skipped.
void relaxPass(WorkMesh& m, const ImplicitSurface& s, bool tangential = true) {
  for (int v = 0; v < int(m.p.size()); ++v) {
    Vec3 centroid = Vec3::Zero(), normal = Vec3::Zero();
    double total = 0;
    for (int fi : m.vf[v]) {
      const Tri& t = m.f[fi];
      const Vec3 area_normal = m.areaNormal(t);
      const Vec3 c = (m.p[t[0]] + m.p[t[1]] + m.p[t[2]]) / 3.0;
      const double rel = s.relative_edge_length(c);
      const double w = area_normal.norm() / (rel * rel);
      centroid += w * c;
      total += w;
      normal += area_normal;
    }
    if (!(total > 0) || !(normal.norm() > 0)) continue;
    centroid /= total;
    normal.normalize();
    const Vec3 moved =
        tangential ? Vec3(centroid + normal * normal.dot(m.p[v] - centroid)) : m.p[v];
    const Vec3 target = projectOntoSurface(s, moved, tangential ? 3 : 6);
    bool ok = true;
    for (int fi : m.vf[v]) {
      const Tri& t = m.f[fi];
      const Vec3 old_normal = m.areaNormal(t);
      std::array<Vec3, 3> q;
      for (int k = 0; k < 3; ++k) q[k] = t[k] == v ? target : m.p[t[k]];
      const Vec3 new_normal = (q[1] - q[0]).cross(q[2] - q[0]);
      const double new_quality = shapeQuality(q[0], q[1], q[2]);
      if (!(new_normal.norm() > 1e-18) ||
          new_normal.dot(old_normal) < 0.5 * new_normal.norm() * old_normal.norm() ||
          (new_quality < kMinQuality &&
           new_quality < shapeQuality(m.p[t[0]], m.p[t[1]], m.p[t[2]]))) {
        ok = false;
        break;
      }
    }
    if (ok) m.p[v] = target;
  }
}

}  // namespace

Vec3 projectOntoSurface(const ImplicitSurface& surface, const Vec3& p, int max_steps) {
  Vec3 q = p;
  for (int step = 0; step < max_steps; ++step) {
    const double f = surface.value(q);
    if (std::abs(f) < 1e-9) break;
    const Vec3 g = centralGradient(surface, q, 1e-6);
    const double g2 = g.squaredNorm();
    if (!(g2 > 1e-12)) break;
    q -= (f / g2) * g;
  }
  return q;
}

TriangleMesh meshImplicitSurface(const ImplicitSurface& surface, const MesherOptions& options) {
  const Soup soup = largestComponent(marchingTetrahedra(surface, options.grid_spacing));
  const long nv = long(soup.points.size()), nf = long(soup.faces.size());
  // Closed manifold surface: every edge in two faces, so E = 3F/2; genus 0: V − E + F = 2.
  if (2 * nv - nf != 4)
    throw Error("synthetic body mesher: the isosurface has " + std::to_string(nv) +
                " vertices and " + std::to_string(nf) +
                " faces, expected a closed genus-0 surface (F = 2V - 4)");
  if (nv < options.vertices)
    throw Error("synthetic body mesher: the isosurface has only " + std::to_string(nv) +
                " vertices, fewer than the " + std::to_string(options.vertices) +
                " requested (grid spacing " + std::to_string(options.grid_spacing) + " m)");
  WorkMesh m(soup);
  decimate(m, surface, options.vertices);
  compact(m);
  for (int round = 0; round < options.relax_rounds; ++round) {
    for (int pass = 0; pass < 10 && flipPass(m) > 0; ++pass) {
    }
    relaxPass(m, surface);
  }
  for (int pass = 0; pass < 10 && flipPass(m) > 0; ++pass) {
  }
  relaxPass(m, surface, /*tangential=*/false);  // every vertex onto the surface

  TriangleMesh out;
  out.vertices.resize(long(m.p.size()), 3);
  for (long v = 0; v < long(m.p.size()); ++v) out.vertices.row(v) = m.p[v].transpose();
  out.faces.resize(long(m.f.size()), 3);
  for (long fi = 0; fi < long(m.f.size()); ++fi)
    out.faces.row(fi) << m.f[fi][0], m.f[fi][1], m.f[fi][2];
  return out;
}

}  // namespace flsh::synthetic
