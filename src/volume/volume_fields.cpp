// Harmonic extension of the body's fields to the tet mesh, rest nodes of a body shape, bone
// nodes (volume_fields.h).
#include "flsh/volume/volume_fields.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <string>

#include "flsh/core/error.h"
#include "volume/kinematic_tree.h"
#include "volume/sparse_cholesky.h"
#include "volume/surface_query.h"

namespace flsh {

namespace {

// Surface nodes must match the body's template vertices this closely (m): the tet mesher keeps
// them bit for bit, so anything larger means the mesh belongs to another body.
constexpr double kSurfaceMatchTolerance = 1e-6;

std::string shape2(long rows, long cols) { return shapeString({rows, cols}); }

/// Distance from x to the segment [a, b] (a point when a = b).
double segmentDistance(const Vec3& x, const Vec3& a, const Vec3& b) {
  const Vec3 ab = b - a;
  const double length_squared = ab.squaredNorm();
  const double t = length_squared > 0 ? std::clamp((x - a).dot(ab) / length_squared, 0.0, 1.0) : 0;
  return (x - a - t * ab).norm();
}

}  // namespace

SpMat cotangentLaplacian(const TetMesh& mesh) {
  detail::checkTetMesh(mesh, mesh.nodes, "cotangentLaplacian");
  std::vector<Triplet> triplets;
  triplets.reserve(size_t(mesh.numTets()) * 16);
  for (int t = 0; t < mesh.numTets(); ++t) {
    const Vec3 x0 = mesh.nodes.row(mesh.tets(t, 0));
    Mat3 edges;
    for (int k = 0; k < 3; ++k) edges.col(k) = mesh.nodes.row(mesh.tets(t, k + 1)).transpose() - x0;
    const double volume = edges.determinant() / 6;
    // Rows of edges⁻¹ are the gradients of the barycentric functions of nodes 1..3.
    const Mat3 inverse = edges.inverse();
    Eigen::Matrix<double, 4, 3> gradients;
    gradients.bottomRows<3>() = inverse;
    gradients.row(0) = -inverse.colwise().sum();
    const Eigen::Matrix4d local = volume * gradients * gradients.transpose();
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j)
        triplets.emplace_back(mesh.tets(t, i), mesh.tets(t, j), local(i, j));
  }
  SpMat K(mesh.numNodes(), mesh.numNodes());
  K.setFromTriplets(triplets.begin(), triplets.end());
  return K;
}

// ---------------------------------------------------------------------------------------------
// HarmonicExtension

struct HarmonicExtension::Factor {
  int num_nodes = 0, num_surface = 0;
  SpMat coupling;                                    ///< K_IB, N_I × V
  std::unique_ptr<detail::SparseCholesky> interior;  ///< K_II (null without interior nodes)
};

HarmonicExtension::HarmonicExtension(const TetMesh& mesh) {
  const SpMat K = cotangentLaplacian(mesh);
  auto f = std::make_shared<Factor>();
  f->num_nodes = mesh.numNodes();
  f->num_surface = mesh.num_surface_nodes;
  const int interior = f->num_nodes - f->num_surface;
  if (interior > 0) {
    if (f->num_surface == 0)
      throw InputError(
          "HarmonicExtension: the tet mesh has 0 surface nodes, expected the "
          "boundary as nodes 0..V−1 (Dirichlet data)");
    f->coupling = K.bottomLeftCorner(interior, f->num_surface);
    try {
      f->interior = std::make_unique<detail::SparseCholesky>(
          K.bottomRightCorner(interior, interior), "HarmonicExtension");
    } catch (const InputError&) {
      throw;
    } catch (const Error& e) {
      throw Error(std::string(e.what()) +
                  ": the interior block of the Laplacian is singular, some interior nodes are "
                  "not connected to the surface");
    }
  }
  factor_ = std::move(f);
}

int HarmonicExtension::numNodes() const { return factor_->num_nodes; }
int HarmonicExtension::numSurfaceNodes() const { return factor_->num_surface; }

MatX HarmonicExtension::extend(const MatX& surface_values) const {
  const Factor& f = *factor_;
  if (surface_values.rows() != f.num_surface)
    throw InputError("HarmonicExtension::extend: surface_values has shape " +
                     shape2(surface_values.rows(), surface_values.cols()) + ", expected " +
                     std::to_string(f.num_surface) + " rows (V surface nodes)");
  if (!surface_values.allFinite())
    throw InputError("HarmonicExtension::extend: surface_values contains NaN or Inf");
  const int interior = f.num_nodes - f.num_surface;
  const Eigen::Index k = surface_values.cols();
  MatX out(f.num_nodes, k);
  out.topRows(f.num_surface) = surface_values;
  if (interior == 0 || k == 0) return out;
  out.bottomRows(interior) = f.interior->solve(-(f.coupling * surface_values));
  return out;
}

// ---------------------------------------------------------------------------------------------
// Body fields

InteriorFields extendBodyFields(const TetMesh& mesh, const BodyModel& body,
                                const HarmonicExtension& harmonic) {
  const std::string fn = "extendBodyFields: ";
  const int nv = body.numVertices(), n = mesh.numNodes();
  if (mesh.num_surface_nodes != nv)
    throw InputError(fn + "the tet mesh has " + std::to_string(mesh.num_surface_nodes) +
                     " surface nodes, the body (" + body.source + ") " + std::to_string(nv) +
                     " vertices; expected the same");
  if (harmonic.numNodes() != n || harmonic.numSurfaceNodes() != nv)
    throw InputError(fn + "the harmonic extension was built on a mesh with " +
                     std::to_string(harmonic.numNodes()) + " nodes (" +
                     std::to_string(harmonic.numSurfaceNodes()) + " surface), expected " +
                     std::to_string(n) + " (" + std::to_string(nv) + ")");
  const int nb = int(body.weights.cols()), K = int(body.shapedirs.cols()),
            P = int(body.posedirs.cols());
  if (body.weights.rows() != nv || body.shapedirs.rows() != 3 * nv ||
      body.posedirs.rows() != 3 * nv || body.v_template.rows() != nv)
    throw InputError(fn + "body (" + body.source + ") arrays are inconsistent: weights " +
                     shape2(body.weights.rows(), nb) + ", shapedirs " +
                     shape2(body.shapedirs.rows(), K) + ", posedirs " +
                     shape2(body.posedirs.rows(), P) + " for " + std::to_string(nv) +
                     " vertices (call BodyModel::validate)");
  const double mismatch =
      nv > 0 ? (mesh.nodes.topRows(nv) - body.v_template).cwiseAbs().maxCoeff() : 0.0;
  if (!(mismatch <= kSurfaceMatchTolerance))
    throw InputError(fn + "surface nodes differ from the body's (" + body.source +
                     ") template vertices by up to " + std::to_string(mismatch) +
                     " m, expected ≤ 1e-6 m (a tet mesh of this body)");

  // One right-hand side matrix: [weights | shapedirs as V × 3K | posedirs as V × 3P], column
  // 3k + c of a vector field holding coordinate c of direction k.
  // Loops run down columns (both matrices are column-major): stride 3 instead of a row's width.
  MatX surface(nv, nb + 3 * K + 3 * P);
  surface.leftCols(nb) = body.weights;
  auto gather = [&](const MatX& field, int first_column) {
    for (Eigen::Index k = 0; k < field.cols(); ++k)
      for (int c = 0; c < 3; ++c)
        for (int i = 0; i < nv; ++i) surface(i, first_column + 3 * k + c) = field(3 * i + c, k);
  };
  gather(body.shapedirs, nb);
  gather(body.posedirs, nb + 3 * K);
  const MatX all = harmonic.extend(surface);

  InteriorFields fields;
  fields.weights = all.leftCols(nb);
  fields.weights.topRows(nv) = body.weights;
  for (int i = nv; i < n; ++i) {
    auto row = fields.weights.row(i);
    const Eigen::RowVectorXd harmonic_row = row;
    row = row.cwiseMax(0.0);
    const double sum = row.sum();
    if (sum > 0) {
      row /= sum;
    } else {  // every weight clamped (cannot happen for convex data; kept total): one-hot
      int largest = 0;
      harmonic_row.maxCoeff(&largest);
      row.setZero();
      row[largest] = 1;
    }
  }
  auto scatter = [&](MatX& field, int columns, int first_column) {
    field.resize(3 * Eigen::Index(n), columns);
    for (int k = 0; k < columns; ++k)
      for (int c = 0; c < 3; ++c)
        for (int i = 0; i < n; ++i) field(3 * i + c, k) = all(i, first_column + 3 * k + c);
  };
  scatter(fields.shapedirs, K, nb);
  scatter(fields.posedirs, P, nb + 3 * K);
  return fields;
}

MatX3 shapedNodes(const TetMesh& mesh, const InteriorFields& fields, const VecX& betas) {
  const std::string fn = "shapedNodes: ";
  const Eigen::Index n = mesh.numNodes(), K = fields.shapedirs.cols();
  if (fields.shapedirs.rows() != 3 * n)
    throw InputError(fn + "fields.shapedirs has shape " + shape2(fields.shapedirs.rows(), K) +
                     ", expected " + std::to_string(3 * n) + " rows (3#N)");
  if (betas.size() > K)
    throw InputError(fn + "betas has " + std::to_string(betas.size()) +
                     " values, expected at most " + std::to_string(K) + " (K shape directions)");
  if (!betas.allFinite()) throw InputError(fn + "betas contains NaN or Inf");
  MatX3 nodes = mesh.nodes;
  if (betas.size() == 0) return nodes;
  const VecX offsets = fields.shapedirs.leftCols(betas.size()) * betas;
  nodes += Eigen::Map<const MatX3>(offsets.data(), n, 3);
  return nodes;
}

// ---------------------------------------------------------------------------------------------
// Bone nodes

VecX nodeDepths(const TetMesh& mesh, const MatX3& shaped_nodes) {
  detail::checkTetMesh(mesh, shaped_nodes, "nodeDepths", false);
  const MatX3i F = detail::outwardBoundaryFaces(mesh, "nodeDepths");
  VecX depth = VecX::Zero(mesh.numNodes());
  if (F.rows() == 0) return depth;
  const detail::SurfaceDistance surface(shaped_nodes, F);
#pragma omp parallel for schedule(static)
  for (int i = mesh.num_surface_nodes; i < mesh.numNodes(); ++i)
    depth[i] = surface.closest(shaped_nodes.row(i).transpose()).distance;
  return depth;
}

namespace {
// Every bone with nodes keeps at least this many (or this fraction of the nodes it dominates)
// attached to it.
constexpr int kMinAnchorNodes = 4;
constexpr double kMinAnchorFraction = 0.05;
}  // namespace

VecXi selectBoneNodes(const TetMesh& mesh, const MatX3& shaped_nodes, const MatX& weights,
                      const MatX3& joints, const std::vector<int>& parents,
                      const VecX& surface_tissue_thickness) {
  const std::string fn = "selectBoneNodes: ";
  detail::checkTetMesh(mesh, shaped_nodes, "selectBoneNodes", false);
  const int n = mesh.numNodes(), nv = mesh.num_surface_nodes, nb = int(joints.rows());
  if (weights.rows() != n || weights.cols() != nb)
    throw InputError(fn + "weights has shape " + shape2(weights.rows(), weights.cols()) +
                     ", expected " + shape2(n, nb) + " (#N × bones)");
  detail::checkParents(parents, nb, fn);
  if (surface_tissue_thickness.size() != nv)
    throw InputError(fn + "surface_tissue_thickness has " +
                     std::to_string(surface_tissue_thickness.size()) + " values, expected " +
                     std::to_string(nv) + " (V surface nodes)");
  if (!weights.allFinite() || !joints.allFinite() || !surface_tissue_thickness.allFinite())
    throw InputError(fn + "weights, joints or surface_tissue_thickness contains NaN or Inf");
  if (nv > 0 && surface_tissue_thickness.minCoeff() < 0)
    throw InputError(fn + "surface_tissue_thickness has a negative value " +
                     std::to_string(surface_tissue_thickness.minCoeff()) + " m, expected ≥ 0");

  VecXi bone = VecXi::Constant(n, -1);
  const MatX3i F = detail::outwardBoundaryFaces(mesh, "selectBoneNodes");
  if (F.rows() == 0 || nv == n) return bone;
  const std::vector<std::vector<int>> children = detail::jointChildren(parents);
  auto boneDistance = [&](const Vec3& x, int b) {
    const Vec3 joint = joints.row(b).transpose();
    if (children[b].empty()) return (x - joint).norm();
    double d = std::numeric_limits<double>::infinity();
    for (int c : children[b]) d = std::min(d, segmentDistance(x, joint, joints.row(c).transpose()));
    return d;
  };

  const detail::SurfaceDistance surface(shaped_nodes, F);
#pragma omp parallel for schedule(static)
  for (int i = nv; i < n; ++i) {
    const Vec3 x = shaped_nodes.row(i).transpose();
    const detail::SurfaceDistance::Hit hit = surface.closest(x);
    double thickness = 0;
    for (int c = 0; c < 3; ++c)
      thickness += hit.barycentric[c] * surface_tissue_thickness[F(hit.face, c)];
    if (!(hit.distance > thickness)) continue;
    const double largest = weights.row(i).maxCoeff();
    int attached = -1;
    double attached_distance = std::numeric_limits<double>::infinity();
    for (int b = 0; b < nb; ++b) {
      if (weights(i, b) != largest) continue;
      const double d = boneDistance(x, b);
      if (d < attached_distance) attached = b, attached_distance = d;
    }
    bone[i] = attached;
  }

  // Anchors: where a bone has fewer deep nodes than kMinAnchorFraction of the nodes it
  // dominates (thin parts such as hands and forearms, whose interior a coarse mesh barely
  // samples), the nodes it dominates nearest to its segment are attached too, interior ones
  // first, then surface ones. Without them such a part would hang on soft tissue alone.
  std::vector<std::vector<std::pair<double, int>>> dominated(nb);  // (key, node)
  std::vector<int> attached_count(nb, 0);
  for (int i = 0; i < n; ++i) {
    if (bone[i] >= 0) {
      ++attached_count[bone[i]];
      continue;
    }
    const Vec3 x = shaped_nodes.row(i).transpose();
    const double largest = weights.row(i).maxCoeff();
    int owner = -1;
    double owner_distance = std::numeric_limits<double>::infinity();
    for (int b = 0; b < nb; ++b) {
      if (weights(i, b) != largest) continue;
      const double d = boneDistance(x, b);
      if (d < owner_distance) owner = b, owner_distance = d;
    }
    // Only overflowing positions (finite but absurd joints) leave every distance non-finite.
    if (owner < 0)
      throw InputError(fn + "node " + std::to_string(i) +
                       " has no finite distance to the bones it is weighted to (joint or node "
                       "positions too large)");
    // Surface nodes sort after every interior node: key = distance + (surface ? 1e6 : 0).
    dominated[owner].emplace_back(owner_distance + (i < nv ? 1e6 : 0.0), i);
  }
  for (int b = 0; b < nb; ++b) {
    const int total = attached_count[b] + int(dominated[b].size());
    const int wanted =
        std::min(total, std::max(kMinAnchorNodes, int(std::ceil(kMinAnchorFraction * total))));
    if (attached_count[b] >= wanted) continue;
    std::sort(dominated[b].begin(), dominated[b].end());
    for (int k = 0; k < wanted - attached_count[b]; ++k) bone[dominated[b][k].second] = b;
  }
  return bone;
}

}  // namespace flsh
