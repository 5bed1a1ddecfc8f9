// Bone mass properties of a closed surface filled with a uniform density: voxel moments lumped
// to vertices (computeVertexMassMoments, steps 1–4a) and spread over bones (lumpBoneInertia,
// step 4b); computeBoneInertia is the two in sequence.
//
// Pipeline:
// 1. Columns: a regular grid of vertical lines (along z) at voxel centres (x_i, y_j). Every
//    triangle is rasterized onto the columns its xy projection covers; where it covers one, the
//    surface crosses that column at the height interpolated over the triangle. Sorting the
//    crossings of a column and pairing them (ray parity) gives the exact inside intervals.
//    Columns exactly on a projected edge or vertex follow a top-left fill rule evaluated with
//    edge functions in a canonical vertex order, so that a column through a shared edge or
//    vertex is counted by exactly one of the triangles meeting there (or by both faces of a
//    silhouette fold: two crossings at one height, parity unchanged). The grid origin is also
//    shifted by a small fixed irrational fraction of a voxel so that such ties are rare to begin
//    with.
// 2. Pieces: each inside interval is cut at the voxel layers z_k; a piece is a box h × h × L
//    (L ≤ h, exact at the surface along z).
// 3. Nearest surface vertex of every piece centre (uniform grid over the vertices, searched in
//    rings of cells); ties go to the smaller vertex index, so the answer does not depend on the
//    search order. This is the only costly step and runs in parallel; each piece's answer is a
//    pure function of its centre and results are stored per piece.
// 4. Accumulation, serial and in piece order (deterministic whatever the thread count): (a) each
//    piece's mass, first and second moments (including its own box inertia) go to its nearest
//    vertex, about that vertex; (b) every vertex spreads its moments over the bones by its
//    skinning weights, shifted to each bone's joint centre (SoftAvatar moves the template's
//    vertex moments to the shaped vertices first: see soft_avatar.h).
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/volume/soft_avatar.h"
#include "volume/voxel_columns.h"

namespace flsh {

namespace {

// More voxels than this in the bounding box is a voxel size far too small for the body.
constexpr double kMaxVoxels = 4e8;

struct Point2 {
  double x, y;
};

bool lexicographicLess(const Point2& a, const Point2& b) {
  return a.x < b.x || (a.x == b.x && a.y < b.y);
}

// Twice the signed area of (s, e, p), positive when p is left of s → e. Evaluated with the
// edge's endpoints in lexicographic order, so the two triangles sharing an edge get exactly
// opposite values (bitwise), which makes the fill rule consistent.
// A point on an endpoint gets an exact 0 (the products below need not cancel exactly when the
// compiler fuses a multiply-add), so the fill rule decides vertices as it does in exact arithmetic.
double edgeFunction(const Point2& s, const Point2& e, const Point2& p) {
  if (lexicographicLess(e, s)) return -edgeFunction(e, s, p);
  if ((p.x == s.x && p.y == s.y) || (p.x == e.x && p.y == e.y)) return 0;
  return (e.x - s.x) * (p.y - s.y) - (e.y - s.y) * (p.x - s.x);
}

// Top-left rule for a counter-clockwise triangle (y up): a point on an edge belongs to the
// triangle if the edge goes down, or is horizontal and goes left.
bool ownsEdge(const Point2& s, const Point2& e) { return e.y < s.y || (e.y == s.y && e.x < s.x); }

bool coversPoint(double w, const Point2& s, const Point2& e) {
  return w > 0 || (w == 0 && ownsEdge(s, e));
}

struct Crossing {
  long column;
  double z;
  bool operator<(const Crossing& o) const {
    return column < o.column || (column == o.column && z < o.z);
  }
};

// A box-shaped piece of the inside: h × h in xy, `length` along z, centred at `centre`.
struct Piece {
  Vec3 centre;
  double length;
};

// Uniform grid over the vertices (CSR: vertices of cell c are index[start[c] .. start[c+1])).
class VertexGrid {
 public:
  VertexGrid(const MatX3& V, double cell) : V_(V), cell_(cell) {
    lo_ = V.colwise().minCoeff().transpose();
    for (int a = 0; a < 3; ++a) {
      const double extent = V.col(a).maxCoeff() - lo_[a];
      n_[a] = std::max(1, int(std::floor(extent / cell_)) + 1);
    }
    const long cells = long(n_[0]) * n_[1] * n_[2];
    start_.assign(cells + 1, 0);
    std::vector<long> cell_of(V.rows());
    for (int i = 0; i < V.rows(); ++i) {
      cell_of[i] = cellIndex(cellCoord(V.row(i).transpose()));
      ++start_[cell_of[i] + 1];
    }
    for (long c = 0; c < cells; ++c) start_[c + 1] += start_[c];
    index_.resize(V.rows());
    std::vector<int> fill(start_.begin(), start_.end() - 1);
    for (int i = 0; i < V.rows(); ++i) index_[fill[cell_of[i]]++] = i;  // ascending per cell
  }

  /// Index of the vertex nearest to x (the smallest index among equally near ones).
  int nearest(const Vec3& x, int guess) const {
    int best = guess;
    double best_d2 = (V_.row(guess).transpose() - x).squaredNorm();
    const Eigen::Vector3i c = cellCoord(x);
    const int max_ring = std::max({n_[0], n_[1], n_[2]});
    for (int k = 0; k <= max_ring; ++k) {
      // Cells of ring k + 1 are at least k cells away from x: nothing nearer there.
      if (k > 0 && best_d2 < (double(k - 1) * cell_) * (double(k - 1) * cell_)) break;
      visitRing(c, k, x, best, best_d2);
    }
    return best;
  }

 private:
  Eigen::Vector3i cellCoord(const Vec3& x) const {
    Eigen::Vector3i c;
    for (int a = 0; a < 3; ++a)
      c[a] = std::clamp(int(std::floor((x[a] - lo_[a]) / cell_)), 0, n_[a] - 1);
    return c;
  }
  long cellIndex(const Eigen::Vector3i& c) const {
    return (long(c[2]) * n_[1] + c[1]) * n_[0] + c[0];
  }

  void visitCell(int i, int j, int k, const Vec3& x, int& best, double& best_d2) const {
    if (i < 0 || j < 0 || k < 0 || i >= n_[0] || j >= n_[1] || k >= n_[2]) return;
    const long c = cellIndex({i, j, k});
    if (start_[c] == start_[c + 1]) return;
    // Skip cells whose box is farther than the best vertex so far (most of a ring).
    const int cell[3] = {i, j, k};
    double box_d2 = 0;
    for (int a = 0; a < 3; ++a) {
      const double below = lo_[a] + cell[a] * cell_ - x[a],
                   above = x[a] - lo_[a] - (cell[a] + 1) * cell_;
      const double gap = std::max({below, above, 0.0});
      box_d2 += gap * gap;
    }
    if (box_d2 > best_d2) return;
    for (int s = start_[c]; s < start_[c + 1]; ++s) {
      const int v = index_[s];
      const double d2 = (V_.row(v).transpose() - x).squaredNorm();
      if (d2 < best_d2 || (d2 == best_d2 && v < best)) {
        best_d2 = d2;
        best = v;
      }
    }
  }

  // The cells at Chebyshev distance exactly k from cell c.
  void visitRing(const Eigen::Vector3i& c, int k, const Vec3& x, int& best, double& best_d2) const {
    for (int dz = -k; dz <= k; ++dz)
      for (int dy = -k; dy <= k; ++dy) {
        if (std::abs(dz) == k || std::abs(dy) == k) {
          for (int dx = -k; dx <= k; ++dx)
            visitCell(c[0] + dx, c[1] + dy, c[2] + dz, x, best, best_d2);
        } else {
          visitCell(c[0] - k, c[1] + dy, c[2] + dz, x, best, best_d2);
          if (k > 0) visitCell(c[0] + k, c[1] + dy, c[2] + dz, x, best, best_d2);
        }
      }
  }

  const MatX3& V_;
  double cell_;
  Vec3 lo_;
  int n_[3];
  std::vector<int> start_;
  std::vector<int> index_;
};

void checkSurface(const MatX3& V, const MatX3i& F, double density, double voxel_size,
                  const std::string& fn = "computeVertexMassMoments: ") {
  if (V.rows() < 4)
    throw InputError(fn + "V has " + std::to_string(V.rows()) +
                     " vertices, expected at least 4 (a closed surface)");
  if (!V.allFinite()) throw InputError(fn + "V contains NaN or Inf");
  if (F.rows() < 4)
    throw InputError(fn + "F has " + std::to_string(F.rows()) +
                     " triangles, expected at least 4 (a closed surface)");
  if (F.minCoeff() < 0 || F.maxCoeff() >= V.rows())
    throw InputError(fn + "F has vertex indices in [" + std::to_string(F.minCoeff()) + ", " +
                     std::to_string(F.maxCoeff()) + "], expected [0, " +
                     std::to_string(V.rows() - 1) + "]");
  if (!(density > 0) || !std::isfinite(density))
    throw InputError(fn + "density = " + std::to_string(density) +
                     ", expected finite and > 0 kg/m³");
  if (!(voxel_size > 0) || !std::isfinite(voxel_size))
    throw InputError(fn + "voxel_size = " + std::to_string(voxel_size) +
                     ", expected finite and > 0 m");
  const Vec3 extent = V.colwise().maxCoeff() - V.colwise().minCoeff();
  const double voxels = (extent.array() / voxel_size + 2).prod();
  if (voxels > kMaxVoxels)
    throw InputError(fn + "voxel_size = " + std::to_string(voxel_size) + " m gives " +
                     std::to_string(voxels) + " voxels over the bounding box, expected at most " +
                     std::to_string(kMaxVoxels) + " (use a larger voxel_size)");
}

void checkInputs(const MatX3& V, const MatX3i& F, const MatX& weights, const MatX3& J,
                 double density, double voxel_size) {
  const std::string fn = "computeBoneInertia: ";
  checkSurface(V, F, density, voxel_size, fn);
  if (weights.rows() != V.rows() || weights.cols() < 1)
    throw InputError(fn + "weights has shape " +
                     shapeString({long(weights.rows()), long(weights.cols())}) + ", expected (" +
                     std::to_string(V.rows()) + ", bones)");
  if (!weights.allFinite()) throw InputError(fn + "weights contains NaN or Inf");
  if (J.rows() != weights.cols())
    throw InputError(fn + "J has shape " + shapeString({long(J.rows()), 3}) + ", expected (" +
                     std::to_string(weights.cols()) + ", 3) (one joint per weights column)");
  if (!J.allFinite()) throw InputError(fn + "J contains NaN or Inf");
}

}  // namespace

VertexMassMoments computeVertexMassMoments(const MatX3& V, const MatX3i& F, double density,
                                           double voxel_size) {
  checkSurface(V, F, density, voxel_size);
  const double h = voxel_size;
  const Vec3 lo = V.colwise().minCoeff(), hi = V.colwise().maxCoeff();
  const voxel::ColumnGrid grid = voxel::columnGrid(lo, hi, h);
  const double ox = grid.origin_x, oy = grid.origin_y, oz = grid.origin_z;
  const long nx = grid.nx, ny = grid.ny;

  // 1. Crossings of the surface with every column.
  std::vector<Crossing> crossings;
  crossings.reserve(size_t(4 * F.rows()));
  for (int f = 0; f < F.rows(); ++f) {
    Vec3 P[3] = {V.row(F(f, 0)), V.row(F(f, 1)), V.row(F(f, 2))};
    Point2 q[3] = {{P[0].x(), P[0].y()}, {P[1].x(), P[1].y()}, {P[2].x(), P[2].y()}};
    const double area2 = edgeFunction(q[0], q[1], q[2]);
    if (area2 == 0) continue;  // seen edge-on: its neighbours' edges carry the crossings
    if (area2 < 0) {           // make the projection counter-clockwise
      std::swap(P[1], P[2]);
      std::swap(q[1], q[2]);
    }
    const double minx = std::min({q[0].x, q[1].x, q[2].x}),
                 maxx = std::max({q[0].x, q[1].x, q[2].x});
    const double miny = std::min({q[0].y, q[1].y, q[2].y}),
                 maxy = std::max({q[0].y, q[1].y, q[2].y});
    // Candidate columns, one wider on each side than the rounded range: the edge functions
    // decide exactly, so a column through a projected vertex is never skipped by rounding here.
    const long i0 = std::max(0L, long(std::ceil((minx - ox) / h - 0.5)) - 1);
    const long i1 = std::min(nx - 1, long(std::floor((maxx - ox) / h - 0.5)) + 1);
    const long j0 = std::max(0L, long(std::ceil((miny - oy) / h - 0.5)) - 1);
    const long j1 = std::min(ny - 1, long(std::floor((maxy - oy) / h - 0.5)) + 1);
    for (long j = j0; j <= j1; ++j)
      for (long i = i0; i <= i1; ++i) {
        const Point2 p{grid.columnX(i), grid.columnY(j)};
        const double w0 = edgeFunction(q[1], q[2], p);  // weight of vertex 0
        const double w1 = edgeFunction(q[2], q[0], p);
        const double w2 = edgeFunction(q[0], q[1], p);
        if (!coversPoint(w0, q[1], q[2]) || !coversPoint(w1, q[2], q[0]) ||
            !coversPoint(w2, q[0], q[1]))
          continue;
        // Barycentric height, normalized by the weights' own sum: an exact convex combination.
        const double sum = w0 + w1 + w2;
        const double z = sum > 0 ? (w0 * P[0].z() + w1 * P[1].z() + w2 * P[2].z()) / sum
                                 : (P[0].z() + P[1].z() + P[2].z()) / 3;
        crossings.push_back({j * nx + i, z});
      }
  }
  std::sort(crossings.begin(), crossings.end());

  // 2. Inside intervals of every column, cut into pieces at the voxel layers.
  std::vector<Piece> pieces;
  for (size_t s = 0; s < crossings.size();) {
    size_t e = s;
    while (e < crossings.size() && crossings[e].column == crossings[s].column) ++e;
    const long column = crossings[s].column;
    const double x = grid.columnX(column % nx), y = grid.columnY(column / nx);
    // A closed surface crosses every column an even number of times; an odd count (open
    // surface) leaves its last crossing unpaired and ignored.
    for (size_t c = s; c + 1 < e; c += 2) {
      const double z0 = crossings[c].z, z1 = crossings[c + 1].z;
      // From one layer below the rounded one, so no part of [z0, z1] is skipped by rounding.
      for (long k = long(std::floor((z0 - oz) / h)) - 1; grid.layerZ(k) < z1; ++k) {
        const double a = std::max(z0, grid.layerZ(k)), b = std::min(z1, grid.layerZ(k + 1));
        if (b > a) pieces.push_back({Vec3(x, y, 0.5 * (a + b)), b - a});
      }
    }
    s = e;
  }

  // 3. Nearest surface vertex of every piece. Cells of four mean edge lengths: fewer cells to
  // visit for deep points, and the box test skips most of their vertices (fastest measured).
  double edge_sum = 0;
  for (int f = 0; f < F.rows(); ++f)
    for (int e = 0; e < 3; ++e) edge_sum += (V.row(F(f, e)) - V.row(F(f, (e + 1) % 3))).norm();
  const double mean_edge = edge_sum / (3.0 * F.rows());
  const VertexGrid vertex_grid(V, std::max(4 * mean_edge, 1e-9 + (hi - lo).maxCoeff() / 512));
  std::vector<int> nearest(pieces.size());
  const long num_pieces = long(pieces.size());
#pragma omp parallel
  {
    int guess = 0;  // the previous piece's answer: a tight first bound for the ring search
#pragma omp for schedule(static)
    for (long p = 0; p < num_pieces; ++p) {
      guess = vertex_grid.nearest(pieces[p].centre, guess);
      nearest[p] = guess;
    }
  }

  // 4. Moments per vertex, about the vertex.
  const int nv = int(V.rows());
  VertexMassMoments moments;
  moments.mass = VecX::Zero(nv);
  moments.first_moment = MatX3::Zero(nv, 3);
  moments.second_moment.assign(nv, Mat3::Zero());
  const double xy_inertia = h * h / 12;  // per unit mass, of an h × h cross-section
  for (size_t p = 0; p < pieces.size(); ++p) {
    const int v = nearest[p];
    const double m = density * h * h * pieces[p].length;
    const Vec3 d = pieces[p].centre - V.row(v).transpose();
    moments.mass[v] += m;
    moments.first_moment.row(v) += m * d.transpose();
    Mat3 own = Mat3::Zero();
    own.diagonal() << xy_inertia, xy_inertia, pieces[p].length * pieces[p].length / 12;
    moments.second_moment[v] += m * (d * d.transpose() + own);
  }
  return moments;
}

std::vector<BoneInertia> lumpBoneInertia(const VertexMassMoments& moments, const MatX3& V,
                                         const MatX& weights, const MatX3& J, double mass_scale) {
  const std::string fn = "lumpBoneInertia: ";
  const long nv = V.rows();
  if (moments.mass.size() != nv || moments.first_moment.rows() != nv ||
      long(moments.second_moment.size()) != nv)
    throw InputError(fn + "moments hold " + std::to_string(moments.mass.size()) +
                     " vertices, expected V's " + std::to_string(nv));
  if (weights.rows() != nv || J.rows() != weights.cols())
    throw InputError(fn + "weights has shape " +
                     shapeString({long(weights.rows()), long(weights.cols())}) + " and J " +
                     shapeString({long(J.rows()), 3}) + ", expected (" + std::to_string(nv) +
                     ", bones) and (bones, 3)");
  if (!(mass_scale > 0) || !std::isfinite(mass_scale))
    throw InputError(fn + "mass_scale = " + std::to_string(mass_scale) +
                     ", expected finite and > 0");
  const int nb = int(weights.cols());
  std::vector<BoneInertia> bones(nb);
  for (int v = 0; v < nv; ++v) {
    const double vertex_mass = moments.mass[v];
    if (vertex_mass == 0) continue;
    const Vec3 vertex_first = moments.first_moment.row(v).transpose();
    const Mat3& vertex_second = moments.second_moment[v];
    for (int b = 0; b < nb; ++b) {
      const double w = weights(v, b);
      if (w == 0) continue;
      const Vec3 offset = V.row(v).transpose() - J.row(b).transpose();  // vertex − joint
      BoneInertia& bone = bones[b];
      bone.mass += w * vertex_mass;
      bone.first_moment += w * (vertex_first + vertex_mass * offset);
      bone.second_moment +=
          w * (vertex_second + vertex_first * offset.transpose() +
               offset * vertex_first.transpose() + vertex_mass * offset * offset.transpose());
    }
  }
  for (BoneInertia& bone : bones) {
    // exact symmetry (the sums above are symmetric up to rounding)
    bone.second_moment = 0.5 * (bone.second_moment + bone.second_moment.transpose()).eval();
    if (mass_scale != 1.0) {
      bone.mass *= mass_scale;
      bone.first_moment *= mass_scale;
      bone.second_moment *= mass_scale;
    }
  }
  return bones;
}

std::vector<BoneInertia> computeBoneInertia(const MatX3& V, const MatX3i& F, const MatX& weights,
                                            const MatX3& J, double density, double voxel_size) {
  checkInputs(V, F, weights, J, density, voxel_size);
  return lumpBoneInertia(computeVertexMassMoments(V, F, density, voxel_size), V, weights, J);
}

}  // namespace flsh
