// CGAL stages of the body tetrahedralization (see tetrahedralize.h): Mesh_3 interior points,
// the Delaunay tetrahedralization of surface + interior points, recovery of the surface faces
// the Delaunay tetrahedralization misses by 2–3 / 3–2 flips, and the inside/outside flood fill.
//
// Recovery never adds a point and never removes a surface edge or face once present, so every
// step makes monotone progress on the set of surface faces. Every choice is made from geometry
// and node indices, not from CGAL's memory layout, so the result is deterministic.
#include "cgal/tetrahedralize.h"

#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/AABB_triangle_primitive.h>
#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Delaunay_triangulation_cell_base_3.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Mesh_complex_3_in_triangulation_3.h>
#include <CGAL/Mesh_criteria_3.h>
#include <CGAL/Mesh_triangulation_3.h>
#include <CGAL/Polygon_mesh_processing/self_intersections.h>
#include <CGAL/Polyhedral_mesh_domain_3.h>
#include <CGAL/Side_of_triangle_mesh.h>
#include <CGAL/Spatial_sort_traits_adapter_3.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/Triangulation_cell_base_with_info_3.h>
#include <CGAL/Triangulation_vertex_base_with_info_3.h>
#include <CGAL/hilbert_sort.h>
#include <CGAL/make_mesh_3.h>
#include <CGAL/property_map.h>

#include <algorithm>
#include <chrono>
#include <deque>
#include <numeric>
#include <optional>
#include <string>
#include <unordered_set>
#include <vector>

#include "core/seconds_since.h"
#include "flsh/core/error.h"

namespace flsh::cgal {
namespace {

using K = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = K::Point_3;
using SurfaceMesh = CGAL::Surface_mesh<Point>;

using detail::secondsSince;

Point toPoint(const MatX3& X, Eigen::Index i) { return Point(X(i, 0), X(i, 1), X(i, 2)); }

SurfaceMesh toSurfaceMesh(const MatX3& V, const MatX3i& F) {
  SurfaceMesh mesh;
  mesh.reserve(SurfaceMesh::size_type(V.rows()), SurfaceMesh::size_type(3 * F.rows() / 2),
               SurfaceMesh::size_type(F.rows()));
  for (Eigen::Index i = 0; i < V.rows(); ++i) mesh.add_vertex(toPoint(V, i));
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    const auto face =
        mesh.add_face(SurfaceMesh::Vertex_index(F(f, 0)), SurfaceMesh::Vertex_index(F(f, 1)),
                      SurfaceMesh::Vertex_index(F(f, 2)));
    // The caller has checked that F is a closed, oriented 2-manifold.
    if (face == SurfaceMesh::null_face())
      throw Error("tetrahedralize: face " + std::to_string(f) +
                  " cannot be added to a manifold surface mesh");
  }
  return mesh;
}

// ---------------------------------------------------------------------------------------------
// Interior points (Mesh_3)

using MeshDomain = CGAL::Polyhedral_mesh_domain_3<SurfaceMesh, K>;
using MeshTriangulation =
    CGAL::Mesh_triangulation_3<MeshDomain, CGAL::Default, CGAL::Sequential_tag>::type;
using MeshComplex = CGAL::Mesh_complex_3_in_triangulation_3<MeshTriangulation>;
using MeshCriteria = CGAL::Mesh_criteria_3<MeshTriangulation>;

using TriangleList = std::vector<K::Triangle_3>;
using TrianglePrimitive = CGAL::AABB_triangle_primitive<K, TriangleList::const_iterator>;
using TriangleTree = CGAL::AABB_tree<CGAL::AABB_traits<K, TrianglePrimitive>>;

// ---------------------------------------------------------------------------------------------
// Delaunay tetrahedralization with node indices on vertices and a flood-fill mark on cells

using VertexBase = CGAL::Triangulation_vertex_base_with_info_3<int, K>;
using CellBase =
    CGAL::Triangulation_cell_base_with_info_3<int, K, CGAL::Delaunay_triangulation_cell_base_3<K>>;
using Tds = CGAL::Triangulation_data_structure_3<VertexBase, CellBase>;
using Delaunay = CGAL::Delaunay_triangulation_3<K, Tds>;
using Vh = Delaunay::Vertex_handle;
using Ch = Delaunay::Cell_handle;

struct TripleHash {
  size_t operator()(const std::array<int, 3>& t) const {
    size_t h = size_t(t[0]) * 0x9E3779B97F4A7C15ull;
    h ^= size_t(t[1]) + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2);
    h ^= size_t(t[2]) + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2);
    return h;
  }
};

std::array<int, 3> sortedTriple(int a, int b, int c) {
  std::array<int, 3> t{a, b, c};
  std::sort(t.begin(), t.end());
  return t;
}
uint64_t edgeKey(int a, int b) {
  if (a > b) std::swap(a, b);
  return (uint64_t(uint32_t(a)) << 32) | uint64_t(uint32_t(b));
}

// A surface element crossed by the open segment of a missing surface edge.
struct Crossing {
  bool is_face = false;  // a face (v[0..2]) or an edge (v[0..1]) is crossed
  std::array<Vh, 3> v;
};

class BoundaryRecovery {
 public:
  BoundaryRecovery(Delaunay& tr, const MatX3i& F) : tr_(tr) {
    surface_faces_.reserve(size_t(F.rows()));
    surface_edges_.reserve(size_t(F.rows()) * 3 / 2);
    for (Eigen::Index f = 0; f < F.rows(); ++f) {
      surface_faces_.insert(sortedTriple(F(f, 0), F(f, 1), F(f, 2)));
      for (int k = 0; k < 3; ++k) surface_edges_.insert(edgeKey(F(f, k), F(f, (k + 1) % 3)));
    }
  }

  bool isSurfaceFace(Vh a, Vh b, Vh c) const {
    if (!isNode(a) || !isNode(b) || !isNode(c)) return false;
    return surface_faces_.count(sortedTriple(a->info(), b->info(), c->info())) > 0;
  }
  bool isSurfaceEdge(Vh a, Vh b) const {
    if (!isNode(a) || !isNode(b)) return false;
    return surface_edges_.count(edgeKey(a->info(), b->info())) > 0;
  }

  /// Makes ab an edge of the triangulation; false if no sequence of improving flips was found.
  bool recoverEdge(Vh a, Vh b) {
    for (int iteration = 0; iteration < kMaxIterations; ++iteration) {
      const auto crossed = crossings(a, b);
      if (!crossed) return false;
      if (crossed->empty()) return true;
      bool improved = false;
      for (const Crossing& x : *crossed) {
        const size_t mark = log_.size();
        const bool flipped =
            x.is_face ? (!isSurfaceFace(x.v[0], x.v[1], x.v[2]) && flip23(x.v[0], x.v[1], x.v[2]))
                      : removeEdge(x.v[0], x.v[1], {a, b, a});
        if (flipped && improves(a, b, crossed->size())) {
          improved = true;
          break;
        }
        undo(mark);
      }
      // Removing an edge of a crossed face (keeping a and b in its ring) recovers ab when ab
      // passes beside that edge, e.g. a surface edge whose flipped diagonal is in the mesh with
      // interior nodes between them.
      std::vector<std::pair<Vh, Vh>> face_edges;
      for (const Crossing& x : *crossed)
        if (x.is_face)
          for (int k = 0; k < 3; ++k) {
            Vh u = x.v[size_t(k)], v = x.v[size_t((k + 1) % 3)];
            if (u->info() > v->info()) std::swap(u, v);
            face_edges.emplace_back(u, v);
          }
      std::sort(face_edges.begin(), face_edges.end(), [](const auto& x, const auto& y) {
        return std::make_pair(x.first->info(), x.second->info()) <
               std::make_pair(y.first->info(), y.second->info());
      });
      face_edges.erase(std::unique(face_edges.begin(), face_edges.end()), face_edges.end());
      for (size_t e = 0; e < face_edges.size() && !improved; ++e) {
        const size_t mark = log_.size();
        if (removeEdge(face_edges[e].first, face_edges[e].second, {a, b, a}) &&
            improves(a, b, crossed->size())) {
          improved = true;
          break;
        }
        undo(mark);
      }
      if (!improved) return false;
    }
    return false;
  }

  /// Makes abc a face, given that its three edges exist; false if no improving flips exist.
  bool recoverFace(Vh a, Vh b, Vh c) {
    for (int iteration = 0; iteration < kMaxIterations; ++iteration) {
      if (isFace(a, b, c)) return true;
      const auto pierced = piercingEdges(a, b, c);
      if (!pierced || pierced->empty()) return false;
      bool improved = false;
      for (const auto& edge : *pierced) {
        const size_t mark = log_.size();
        if (removeEdge(edge.first, edge.second, {a, b, c})) {
          if (isFace(a, b, c)) return true;
          const auto after = piercingEdges(a, b, c);
          if (after && after->size() < pierced->size()) {
            improved = true;
            break;
          }
        }
        undo(mark);
      }
      if (!improved) return false;
    }
    return false;
  }

  // Whether segment ab now crosses fewer than `before` faces and edges.
  bool improves(Vh a, Vh b, size_t before) const {
    const auto after = crossings(a, b);
    return after && after->size() < before;
  }

  bool isFace(Vh a, Vh b, Vh c) const {
    Ch cell;
    int i, j, k;
    return tr_.is_facet(a, b, c, cell, i, j, k);
  }
  bool isEdge(Vh a, Vh b) const {
    Ch cell;
    int i, j;
    return tr_.is_edge(a, b, cell, i, j);
  }

 private:
  static constexpr int kMaxIterations = 64;

  // A logged flip and what it created, enough to invert it: a 2–3 flip created edge v[0]v[1],
  // a 3–2 flip created face v[0]v[1]v[2], a 4–4 flip replaced edge v[2]v[3] by edge v[0]v[1].
  enum class FlipKind { two_to_three, three_to_two, four_to_four };
  struct Flip {
    FlipKind kind;
    std::array<Vh, 4> v;
  };

  static bool isNode(Vh v) { return v->info() >= 0; }

  CGAL::Sign orient(Vh p, Vh q, Vh r, Vh s) const {
    return tr_.geom_traits().orientation_3_object()(p->point(), q->point(), r->point(), s->point());
  }

  // 2–3 flip of face uvw (it must not be a surface face); logged for undo.
  bool flip23(Vh u, Vh v, Vh w) {
    Ch cell;
    int i, j, k;
    if (!tr_.is_facet(u, v, w, cell, i, j, k)) return false;
    const int l = 6 - i - j - k;
    const Ch neighbor = cell->neighbor(l);
    if (tr_.is_infinite(cell) || tr_.is_infinite(neighbor)) return false;
    const Vh p = cell->vertex(l), q = neighbor->vertex(neighbor->index(cell));
    if (!tr_.flip(cell, l)) return false;
    log_.push_back({FlipKind::two_to_three, {p, q, p, q}});
    return true;
  }

  // 3–2 flip of edge cd (degree 3, not a surface edge); logged for undo.
  bool flip32(Vh c, Vh d) {
    Ch cell;
    int i, j;
    if (isSurfaceEdge(c, d) || !tr_.is_edge(c, d, cell, i, j)) return false;
    const std::vector<Vh> ring = ringOf(cell, i, j);
    if (ring.size() != 3) return false;
    if (!tr_.flip(cell, i, j)) return false;
    log_.push_back({FlipKind::three_to_two, {ring[0], ring[1], ring[2], ring[0]}});
    return true;
  }

  // Undoes the logged flips after position `mark` (each flip's inverse is always valid).
  void undo(size_t mark) {
    while (log_.size() > mark) {
      const Flip flip = log_.back();
      log_.pop_back();
      bool undone = false;
      if (flip.kind == FlipKind::two_to_three) {
        Ch cell;
        int i, j;
        undone = tr_.is_edge(flip.v[0], flip.v[1], cell, i, j) && tr_.flip(cell, i, j);
      } else if (flip.kind == FlipKind::three_to_two) {
        Ch cell;
        int i, j, k;
        undone = tr_.is_facet(flip.v[0], flip.v[1], flip.v[2], cell, i, j, k) &&
                 tr_.flip(cell, 6 - i - j - k);
      } else {
        undone = flip44(flip.v[0], flip.v[1], flip.v[2], flip.v[3]);
        if (undone) log_.pop_back();
      }
      if (!undone) throw Error("tetrahedralize: internal error, a flip could not be undone");
    }
  }

  // 4–4 flip: edge cd, whose ring is (a, x, b, y) with a, b, c, d coplanar and segment ab
  // crossing segment cd, is replaced by edge ab. No sequence of valid 2–3 / 3–2 flips does this
  // (it is the flip of a diagonal of a flat quadrilateral), so it is done as a combinatorial 2–3
  // flip through a flat tet immediately followed by a 3–2 flip, after checking geometrically
  // that the four final tets are positive. Logged.
  bool flip44(Vh c, Vh d, Vh a, Vh b) {
    Ch cell;
    int i, j;
    if (isSurfaceEdge(c, d) || !tr_.is_edge(c, d, cell, i, j)) return false;
    const std::vector<Vh> ring = ringOf(cell, i, j);
    if (ring.size() != 4) return false;
    int k = 0;
    while (k < 4 && ring[size_t(k)] != a) ++k;
    if (k == 4 || ring[size_t((k + 2) % 4)] != b) return false;
    const Vh x = ring[size_t((k + 1) % 4)], y = ring[size_t((k + 3) % 4)];
    for (const Vh v : {a, b, c, d, x, y})
      if (tr_.is_infinite(v)) return false;
    if (orient(a, b, c, d) != CGAL::ZERO) return false;
    // ab and cd cross properly: c, d on opposite sides of plane abx, a, b of plane cdx.
    const CGAL::Sign c_side = orient(a, b, x, c), d_side = orient(a, b, x, d);
    const CGAL::Sign a_side = orient(c, d, x, a), b_side = orient(c, d, x, b);
    if (c_side == CGAL::ZERO || c_side != -d_side || a_side == CGAL::ZERO || a_side != -b_side)
      return false;
    Ch face_cell;
    int fi, fj, fk;
    if (!tr_.is_facet(c, d, x, face_cell, fi, fj, fk)) return false;
    tr_.tds().flip_flippable(face_cell, 6 - fi - fj - fk);  // creates ab and the flat tet abcd
    if (!tr_.is_edge(c, d, cell, i, j)) throw Error("tetrahedralize: internal error in a 4-4 flip");
    tr_.tds().flip_flippable(cell, i, j);  // removes cd and the flat tet
    log_.push_back({FlipKind::four_to_four, {a, b, c, d}});
    return true;
  }

  // Vertices around edge (cell, i, j) in circular order, starting at the smallest node label.
  std::vector<Vh> ringOf(Ch cell, int i, int j) const {
    std::vector<Vh> ring;
    const Vh c = cell->vertex(i), d = cell->vertex(j);
    auto circulator = tr_.incident_cells(cell, i, j), done = circulator;
    do {
      // The ring vertex shared with the next cell: the vertex of this cell, other than c and d,
      // that the next cell also has.
      const Ch current = circulator;
      ++circulator;
      const Ch next = circulator;
      for (int k = 0; k < 4; ++k) {
        const Vh v = current->vertex(k);
        if (v != c && v != d && next->has_vertex(v)) {
          ring.push_back(v);
          break;
        }
      }
    } while (circulator != done);
    return ring;
  }

  // Removes edge cd by 2–3 flips of the faces around it (shrinking its ring, never dropping a
  // vertex of `keep` from the ring) and a final 3–2 flip. Logged; false if stuck.
  bool removeEdge(Vh c, Vh d, const std::array<Vh, 3>& keep) {
    if (isSurfaceEdge(c, d)) return false;
    for (int step = 0; step < 64; ++step) {
      Ch cell;
      int i, j;
      if (!tr_.is_edge(c, d, cell, i, j)) return true;
      std::vector<Vh> ring = ringOf(cell, i, j);
      for (const Vh v : ring)
        if (tr_.is_infinite(v)) return false;
      if (ring.size() <= 3) return flip32(c, d);
      // Two opposite ring vertices coplanar with cd (a flat quadrilateral): a 4–4 flip.
      if (ring.size() == 4)
        for (int k = 0; k < 2; ++k)
          if (flip44(c, d, ring[size_t(k)], ring[size_t(k + 2)])) return true;
      std::vector<Vh> candidates;
      for (const Vh v : ring)
        if (std::find(keep.begin(), keep.end(), v) == keep.end()) candidates.push_back(v);
      std::sort(candidates.begin(), candidates.end(),
                [](Vh x, Vh y) { return x->info() < y->info(); });
      bool shrunk = false;
      for (const Vh v : candidates) {
        if (flip23(c, d, v)) {
          shrunk = true;
          break;
        }
      }
      if (!shrunk) return false;
    }
    return false;
  }

  // The faces and edges that the open segment ab crosses, in order from a; empty if ab is an
  // edge; nullopt if the segment meets a vertex or runs inside a face, or a cell is infinite.
  std::optional<std::vector<Crossing>> crossings(Vh a, Vh b) const {
    const Point& pa = a->point();
    const Point& pb = b->point();
    const auto orientation = tr_.geom_traits().orientation_3_object();
    const auto sigma = [&](Vh u, Vh v) { return int(orientation(pa, pb, u->point(), v->point())); };
    std::vector<Crossing> out;
    if (isEdge(a, b)) return out;

    // Leave a through the cell whose cone at a contains b.
    std::vector<Ch> around;
    tr_.incident_cells(a, std::back_inserter(around));
    Ch from;
    int from_opposite = -1;  // for a face crossing: index in `from` of the vertex opposite it
    bool found = false;
    for (const Ch cell : around) {
      if (tr_.is_infinite(cell)) continue;
      const int ia = cell->index(a);
      Vh p = cell->vertex((ia + 1) & 3), q = cell->vertex((ia + 2) & 3),
         r = cell->vertex((ia + 3) & 3);
      if (p == b || q == b || r == b) return out;
      if (orient(a, p, q, r) != CGAL::POSITIVE) std::swap(q, r);
      // Signs of b − a in the basis (p − a, q − a, r − a).
      const int alpha = orient(a, b, q, r), beta = orient(a, p, b, r), gamma = orient(a, p, q, b);
      if (alpha < 0 || beta < 0 || gamma < 0) continue;
      const int zeros = (alpha == 0) + (beta == 0) + (gamma == 0);
      if (zeros >= 2) return std::nullopt;  // a vertex lies on the segment
      Crossing x;
      if (zeros == 0) {
        x.is_face = true;
        x.v = {p, q, r};
        from_opposite = ia;
      } else {
        x.is_face = false;
        x.v = alpha == 0 ? std::array<Vh, 3>{q, r, q}
                         : (beta == 0 ? std::array<Vh, 3>{p, r, p} : std::array<Vh, 3>{p, q, p});
      }
      out.push_back(x);
      from = cell;
      found = true;
      break;
    }
    if (!found) return std::nullopt;

    for (int step = 0; step < 100000; ++step) {
      const Crossing& entry = out.back();
      Ch next;
      if (entry.is_face) {
        next = from->neighbor(from_opposite);
      } else {
        // The cell around the crossed edge qr whose open wedge contains b.
        const Vh q = entry.v[0], r = entry.v[1];
        auto circulator = tr_.incident_cells(from, from->index(q), from->index(r)),
             done = circulator;
        bool located = false;
        do {
          const Ch cell = circulator;
          ++circulator;
          if (tr_.is_infinite(cell)) continue;
          if (cell->has_vertex(b)) return out;  // a, b, q, r coplanar: the segment ends at b
          Vh others[2];
          int n = 0;
          for (int k = 0; k < 4; ++k)
            if (cell->vertex(k) != q && cell->vertex(k) != r) others[n++] = cell->vertex(k);
          const Vh u = others[0], w = others[1];
          const CGAL::Sign side_u = orient(q, r, u, b), side_w = orient(q, r, w, b);
          if (side_u != CGAL::ZERO && side_u == orient(q, r, u, w) && side_w != CGAL::ZERO &&
              side_w == orient(q, r, w, u)) {
            next = cell;
            located = true;
            break;
          }
        } while (circulator != done);
        if (!located) return std::nullopt;
      }
      if (tr_.is_infinite(next)) return std::nullopt;
      if (next->has_vertex(b)) return out;

      const auto inEntry = [&](Vh v) {
        return v == entry.v[0] || v == entry.v[1] || (entry.is_face && v == entry.v[2]);
      };
      for (int k = 0; k < 4; ++k)
        if (!inEntry(next->vertex(k)) &&
            tr_.geom_traits().collinear_3_object()(pa, pb, next->vertex(k)->point()))
          return std::nullopt;

      // The exit: a face other than the entry face whose interior the line crosses, or an edge
      // other than the entry edge whose interior it crosses.
      bool exited = false;
      for (int k = 0; k < 4 && !exited; ++k) {
        const Vh x0 = next->vertex((k + 1) & 3), x1 = next->vertex((k + 2) & 3),
                 x2 = next->vertex((k + 3) & 3);
        if (entry.is_face && inEntry(x0) && inEntry(x1) && inEntry(x2)) continue;
        const int s0 = sigma(x0, x1), s1 = sigma(x1, x2), s2 = sigma(x2, x0);
        if (s0 != 0 && s0 == s1 && s1 == s2) {
          out.push_back({true, {x0, x1, x2}});
          from = next;
          from_opposite = k;
          exited = true;
        }
      }
      for (int i = 0; i < 4 && !exited; ++i) {
        for (int j = i + 1; j < 4 && !exited; ++j) {
          const Vh xi = next->vertex(i), xj = next->vertex(j);
          if (!entry.is_face && inEntry(xi) && inEntry(xj)) continue;
          if (sigma(xi, xj) != 0) continue;
          for (int l = 0; l < 4; ++l) {
            if (l == i || l == j) continue;
            const Vh xl = next->vertex(l);
            const int s1 = sigma(xj, xl), s2 = sigma(xl, xi);
            if (s1 != 0 && s1 == s2) {
              out.push_back({false, {xi, xj, xi}});
              from = next;
              exited = true;
              break;
            }
          }
        }
      }
      if (!exited) return std::nullopt;
    }
    return std::nullopt;
  }

  // Edges (by node labels, sorted) that cross the interior of triangle abc, found by a search
  // over the cells that have such an edge; nullopt if a vertex lies in the triangle's plane
  // inside it (no flip can recover the face then).
  std::optional<std::vector<std::pair<Vh, Vh>>> piercingEdges(Vh a, Vh b, Vh c) const {
    const auto pierces = [&](Vh u, Vh v) {
      if (u == a || u == b || u == c || v == a || v == b || v == c) return false;
      if (tr_.is_infinite(u) || tr_.is_infinite(v)) return false;
      const int su = orient(a, b, c, u), sv = orient(a, b, c, v);
      if (su * sv >= 0) return false;
      const int t0 = orient(u, v, a, b), t1 = orient(u, v, b, c), t2 = orient(u, v, c, a);
      return t0 != 0 && t0 == t1 && t1 == t2;
    };
    std::vector<std::pair<Vh, Vh>> edges;
    std::unordered_set<Ch, std::hash<Ch>> seen;
    std::deque<Ch> queue;
    bool degenerate = false;
    const auto visit = [&](Ch cell) {
      if (seen.count(cell) || tr_.is_infinite(cell)) return;
      bool involved = false;
      for (int i = 0; i < 4; ++i)
        for (int j = i + 1; j < 4; ++j)
          if (pierces(cell->vertex(i), cell->vertex(j))) {
            involved = true;
            Vh u = cell->vertex(i), v = cell->vertex(j);
            if (u->info() > v->info()) std::swap(u, v);
            edges.emplace_back(u, v);
          }
      if (involved) {
        seen.insert(cell);
        queue.push_back(cell);
      }
    };
    for (const Vh corner : {a, b, c}) {
      std::vector<Ch> around;
      tr_.incident_cells(corner, std::back_inserter(around));
      for (const Ch cell : around) visit(cell);
      // A vertex inside the triangle, in its plane, blocks every flip sequence.
      std::vector<Vh> neighbors;
      tr_.adjacent_vertices(corner, std::back_inserter(neighbors));
      for (const Vh v : neighbors) {
        if (tr_.is_infinite(v) || v == a || v == b || v == c) continue;
        if (orient(a, b, c, v) != CGAL::ZERO) continue;
        const auto coplanar_orientation = tr_.geom_traits().coplanar_orientation_3_object();
        const auto s0 = coplanar_orientation(a->point(), b->point(), v->point());
        const auto s1 = coplanar_orientation(b->point(), c->point(), v->point());
        const auto s2 = coplanar_orientation(c->point(), a->point(), v->point());
        if (s0 != CGAL::NEGATIVE && s1 != CGAL::NEGATIVE && s2 != CGAL::NEGATIVE &&
            s0 == coplanar_orientation(a->point(), b->point(), c->point()))
          degenerate = true;
      }
    }
    while (!queue.empty()) {
      const Ch cell = queue.front();
      queue.pop_front();
      for (int i = 0; i < 4; ++i) visit(cell->neighbor(i));
    }
    if (degenerate) return std::nullopt;
    std::sort(edges.begin(), edges.end(), [](const auto& x, const auto& y) {
      return std::make_pair(x.first->info(), x.second->info()) <
             std::make_pair(y.first->info(), y.second->info());
    });
    edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
    return edges;
  }

  Delaunay& tr_;
  std::unordered_set<std::array<int, 3>, TripleHash> surface_faces_;
  std::unordered_set<uint64_t> surface_edges_;
  std::vector<Flip> log_;
};

}  // namespace

MatX3 meshInteriorPoints(const MatX3& V, const MatX3i& F, double cell_size, double clearance,
                         unsigned seed) {
  const SurfaceMesh mesh = toSurfaceMesh(V, F);
  CGAL::Random random(seed);
  const MeshDomain domain(mesh, &random);
  namespace params = CGAL::parameters;
  // The surface part of the Mesh_3 output is discarded: the facet criteria only need to keep the
  // restricted surface close enough that cells are classified inside correctly.
  const MeshCriteria criteria(params::facet_size = 4 * cell_size,
                              params::facet_distance = cell_size,
                              params::cell_radius_edge_ratio = 2.5, params::cell_size = cell_size);
  const MeshComplex complex =
      CGAL::make_mesh_3<MeshComplex>(domain, criteria, params::no_perturb(), params::no_exude());

  TriangleList triangles;
  std::vector<double> mean_edge(size_t(F.rows()));
  triangles.reserve(size_t(F.rows()));
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    triangles.emplace_back(toPoint(V, F(f, 0)), toPoint(V, F(f, 1)), toPoint(V, F(f, 2)));
    double sum = 0;
    for (int k = 0; k < 3; ++k) sum += (V.row(F(f, k)) - V.row(F(f, (k + 1) % 3))).norm();
    mean_edge[size_t(f)] = sum / 3;
  }
  TriangleTree tree(triangles.cbegin(), triangles.cend());
  tree.accelerate_distance_queries();
  const CGAL::Side_of_triangle_mesh<SurfaceMesh, K> side(mesh);

  std::vector<std::array<double, 3>> kept;
  const auto& triangulation = complex.triangulation();
  for (auto v = triangulation.finite_vertices_begin(); v != triangulation.finite_vertices_end();
       ++v) {
    if (v->in_dimension() != 3) continue;
    const Point p = v->point().point();
    if (side(p) != CGAL::ON_BOUNDED_SIDE) continue;
    const auto closest = tree.closest_point_and_primitive(p);
    const double limit = clearance * mean_edge[size_t(closest.second - triangles.cbegin())];
    if (CGAL::squared_distance(p, closest.first) < limit * limit) continue;
    kept.push_back({p.x(), p.y(), p.z()});
  }
  std::sort(kept.begin(), kept.end());
  MatX3 points(Eigen::Index(kept.size()), 3);
  for (size_t i = 0; i < kept.size(); ++i)
    points.row(Eigen::Index(i)) << kept[i][0], kept[i][1], kept[i][2];
  return points;
}

std::pair<int, int> firstSelfIntersection(const MatX3& V, const MatX3i& F) {
  const SurfaceMesh mesh = toSurfaceMesh(V, F);
  namespace PMP = CGAL::Polygon_mesh_processing;
  if (!PMP::does_self_intersect(mesh)) return {-1, -1};
  std::vector<std::pair<SurfaceMesh::Face_index, SurfaceMesh::Face_index>> pairs;
  PMP::self_intersections(faces(mesh), mesh, std::back_inserter(pairs));
  std::pair<int, int> first{-1, -1};
  for (const auto& [f, g] : pairs) {
    const std::pair<int, int> candidate = std::minmax(int(f), int(g));
    if (first.first < 0 || candidate < first) first = candidate;
  }
  return first;
}

BoundaryConformingTets boundaryConformingTets(const MatX3& nodes, const MatX3i& F) {
  BoundaryConformingTets result;
  auto start = std::chrono::steady_clock::now();

  // Eight far corners keep the surface off the convex hull, so that every surface face has
  // finite cells on both sides and can be flipped (labels −1..−8; they end up outside).
  std::vector<Point> points;
  points.reserve(size_t(nodes.rows()) + 8);
  for (Eigen::Index i = 0; i < nodes.rows(); ++i) points.push_back(toPoint(nodes, i));
  const Vec3 low = nodes.colwise().minCoeff(), high = nodes.colwise().maxCoeff();
  // Unequal margins, so that no far corner lines up with a face, edge or diagonal of an
  // axis-aligned input such as a box.
  const double margin = std::max((high - low).norm(), 1e-3);
  const Vec3 below = margin * Vec3(1.0, 1.1377, 1.2913), above = margin * Vec3(1.0713, 1.2161, 1.1);
  for (int corner = 0; corner < 8; ++corner)
    points.emplace_back((corner & 1) ? high.x() + above.x() : low.x() - below.x(),
                        (corner & 2) ? high.y() + above.y() : low.y() - below.y(),
                        (corner & 4) ? high.z() + above.z() : low.z() - below.z());
  const auto label = [&](size_t i) {
    return i < size_t(nodes.rows()) ? int(i) : -1 - int(i - size_t(nodes.rows()));
  };

  // Hilbert order without the random shuffle of spatial_sort, so insertion is reproducible.
  std::vector<size_t> order(points.size());
  std::iota(order.begin(), order.end(), 0);
  using SortTraits =
      CGAL::Spatial_sort_traits_adapter_3<K, CGAL::Pointer_property_map<Point>::const_type>;
  CGAL::hilbert_sort(order.begin(), order.end(),
                     SortTraits(CGAL::make_property_map(std::as_const(points))));
  Delaunay tr;
  std::vector<Vh> handle(points.size());
  Ch hint;
  for (const size_t i : order) {
    const size_t before = tr.number_of_vertices();
    const Vh v = tr.insert(points[i], hint);
    if (tr.number_of_vertices() == before)
      throw InputError("tetrahedralize: nodes " + std::to_string(v->info()) + " and " +
                       std::to_string(label(i)) + " coincide; expected distinct positions");
    v->info() = label(i);
    handle[i] = v;
    hint = v->cell();
  }
  result.delaunay_seconds = secondsSince(start);
  start = std::chrono::steady_clock::now();

  BoundaryRecovery recovery(tr, F);
  std::vector<char> was_missing(size_t(F.rows()), 0);
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    was_missing[size_t(f)] = !recovery.isFace(handle[F(f, 0)], handle[F(f, 1)], handle[F(f, 2)]);
  result.missing_faces = int(std::count(was_missing.begin(), was_missing.end(), 1));
  // A second pass retries faces whose flips were blocked before other faces were recovered.
  for (int pass = 0; pass < 2 && result.missing_faces > 0; ++pass) {
    for (Eigen::Index f = 0; f < F.rows(); ++f) {
      if (!was_missing[size_t(f)]) continue;
      const Vh a = handle[F(f, 0)], b = handle[F(f, 1)], c = handle[F(f, 2)];
      if (recovery.isFace(a, b, c)) continue;
      const bool edges = (recovery.isEdge(a, b) || recovery.recoverEdge(a, b)) &&
                         (recovery.isEdge(b, c) || recovery.recoverEdge(b, c)) &&
                         (recovery.isEdge(c, a) || recovery.recoverEdge(c, a));
      if (edges) recovery.recoverFace(a, b, c);
    }
  }
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    if (!was_missing[size_t(f)]) continue;
    if (recovery.isFace(handle[F(f, 0)], handle[F(f, 1)], handle[F(f, 2)])) {
      ++result.recovered_faces;
    } else {
      ++result.unrecovered_faces;
      if (result.example_unrecovered < 0) result.example_unrecovered = int(f);
    }
  }
  result.recovery_seconds = secondsSince(start);
  if (result.unrecovered_faces > 0) return result;
  // The Triangulation_3 check (combinatorics, positive orientation); flips void the Delaunay one.
  if (!tr.Delaunay::Tr_Base::is_valid(false))
    throw Error("tetrahedralize: internal error, the triangulation is invalid after recovery");

  // Inside = the cells not reached from the infinite cells without crossing a surface face.
  std::unordered_set<std::array<int, 3>, TripleHash> surface;
  surface.reserve(size_t(F.rows()));
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    surface.insert(sortedTriple(F(f, 0), F(f, 1), F(f, 2)));
  std::vector<Ch> stack;
  for (auto cell = tr.all_cells_begin(); cell != tr.all_cells_end(); ++cell) {
    cell->info() = tr.is_infinite(cell) ? 1 : 0;
    if (cell->info()) stack.push_back(cell);
  }
  while (!stack.empty()) {
    const Ch cell = stack.back();
    stack.pop_back();
    for (int i = 0; i < 4; ++i) {
      const Ch neighbor = cell->neighbor(i);
      if (neighbor->info()) continue;
      const Vh x = cell->vertex((i + 1) & 3), y = cell->vertex((i + 2) & 3),
               z = cell->vertex((i + 3) & 3);
      if (!tr.is_infinite(x) && !tr.is_infinite(y) && !tr.is_infinite(z) && x->info() >= 0 &&
          y->info() >= 0 && z->info() >= 0 &&
          surface.count(sortedTriple(x->info(), y->info(), z->info())))
        continue;
      neighbor->info() = 1;
      stack.push_back(neighbor);
    }
  }
  std::vector<std::array<int, 4>> inside;
  for (auto cell = tr.finite_cells_begin(); cell != tr.finite_cells_end(); ++cell) {
    if (cell->info()) continue;
    std::array<int, 4> tet;
    for (int k = 0; k < 4; ++k) tet[size_t(k)] = cell->vertex(k)->info();
    if (*std::min_element(tet.begin(), tet.end()) < 0)
      throw Error("tetrahedralize: internal error, an auxiliary far corner was classified inside");
    inside.push_back(tet);  // CGAL's finite cells are positively oriented
  }
  result.tets.resize(Eigen::Index(inside.size()), 4);
  for (size_t t = 0; t < inside.size(); ++t)
    for (int k = 0; k < 4; ++k) result.tets(Eigen::Index(t), k) = inside[t][size_t(k)];
  return result;
}

}  // namespace flsh::cgal
