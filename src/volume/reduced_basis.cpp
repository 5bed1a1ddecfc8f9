// Farthest-point handles and bounded biharmonic weights of the ROM basis (reduced_basis.h).
#include "flsh/volume/reduced_basis.h"

#include <omp.h>

#include <Eigen/SparseCholesky>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <queue>
#include <string>
#include <utility>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/volume/volume_fields.h"
#include "volume/surface_query.h"

namespace flsh {

namespace {

constexpr double kInfinity = std::numeric_limits<double>::infinity();
// Sufficient-decrease constant of the projected searches (Armijo).
constexpr double kArmijo = 1e-4;
// Halvings of a projected search before falling back to a projected-gradient step.
constexpr int kMaxHalvings = 40;

/// Checks the sampling arguments; returns the per-vertex "may not be chosen" flags.
std::vector<char> checkSampling(const MatX3& vertices, int count, int first,
                                const VecXi& bone_of_vertex, const char* who) {
  const std::string fn = std::string(who) + ": ";
  const long num_vertices = vertices.rows();
  if (!vertices.allFinite()) throw InputError(fn + "surface_vertices contain NaN or Inf");
  if (bone_of_vertex.size() != 0 && bone_of_vertex.size() != num_vertices)
    throw InputError(fn + "bone_of_vertex has " + std::to_string(bone_of_vertex.size()) +
                     " entries, expected 0 or #V = " + std::to_string(num_vertices));
  std::vector<char> excluded(num_vertices, 0);
  long eligible = num_vertices;
  for (long i = 0; i < bone_of_vertex.size(); ++i)
    if (bone_of_vertex[i] >= 0) excluded[i] = 1, --eligible;
  if (count < 1 || count > eligible)
    throw InputError(fn + "count = " + std::to_string(count) + ", expected 1.." +
                     std::to_string(eligible) + " (#V = " + std::to_string(num_vertices) +
                     " minus bone-attached vertices)");
  if (first < 0 || first >= num_vertices)
    throw InputError(fn + "first = " + std::to_string(first) +
                     ", expected 0..#V−1 = " + std::to_string(num_vertices - 1));
  if (excluded[first])
    throw InputError(fn + "first = " + std::to_string(first) +
                     " is attached to a bone (bone_of_vertex = " +
                     std::to_string(bone_of_vertex[first]) + "), expected a soft-tissue vertex");
  return excluded;
}

/// The unchosen vertex with the largest distance (lowest index on ties).
int farthestUnchosen(const VecX& distance, const std::vector<char>& chosen) {
  int best = -1;
  for (int i = 0; i < distance.size(); ++i)
    if (!chosen[i] && (best < 0 || distance[i] > distance[best])) best = i;
  return best;
}

/// Symmetric adjacency in compressed rows, with edge lengths.
struct Graph {
  std::vector<int> start, neighbour;
  std::vector<double> length;
};

Graph graphFromPairs(std::vector<std::pair<int, int>> edges, const MatX3& points) {
  std::sort(edges.begin(), edges.end());
  edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
  Graph g;
  g.start.assign(points.rows() + 1, 0);
  for (const auto& e : edges) ++g.start[e.first + 1];
  for (int i = 0; i < points.rows(); ++i) g.start[i + 1] += g.start[i];
  g.neighbour.resize(edges.size());
  g.length.resize(edges.size());
  std::vector<int> fill(g.start.begin(), g.start.end() - 1);
  for (const auto& e : edges) {
    const int k = fill[e.first]++;
    g.neighbour[k] = e.second;
    g.length[k] = (points.row(e.first) - points.row(e.second)).norm();
  }
  return g;
}

using QueueEntry = std::pair<double, int>;
using MinQueue = std::priority_queue<QueueEntry, std::vector<QueueEntry>, std::greater<>>;

}  // namespace

// ---------------------------------------------------------------------------------------------
// Farthest-point sampling

VecXi farthestPointSurfaceHandles(const MatX3& surface_vertices, int count, int first,
                                  const VecXi& bone_of_vertex) {
  const int n = int(surface_vertices.rows());
  std::vector<char> chosen =
      checkSampling(surface_vertices, count, first, bone_of_vertex, "farthestPointSurfaceHandles");
  VecX distance = VecX::Constant(n, kInfinity);
  VecXi handles(count);
  int next = first;
  for (int k = 0; k < count; ++k) {
    handles[k] = next;
    chosen[next] = 1;
    const Eigen::RowVector3d p = surface_vertices.row(next);
    distance = distance.cwiseMin((surface_vertices.rowwise() - p).rowwise().norm());
    if (k + 1 < count) next = farthestUnchosen(distance, chosen);
  }
  return handles;
}

VecXi farthestPointSurfaceHandles(const MatX3& surface_vertices, const MatX3i& surface_faces,
                                  int count, int first, const VecXi& bone_of_vertex) {
  const char* who = "farthestPointSurfaceHandles";
  const int n = int(surface_vertices.rows());
  // Ineligible vertices count as already chosen: never picked, but distances pass through them.
  std::vector<char> chosen = checkSampling(surface_vertices, count, first, bone_of_vertex, who);
  std::vector<std::pair<int, int>> edges;
  edges.reserve(size_t(surface_faces.rows()) * 6);
  for (int f = 0; f < surface_faces.rows(); ++f)
    for (int k = 0; k < 3; ++k) {
      const int a = surface_faces(f, k), b = surface_faces(f, (k + 1) % 3);
      if (a < 0 || a >= n || b < 0 || b >= n)
        throw InputError(std::string(who) + ": surface_faces row " + std::to_string(f) +
                         " has a vertex index outside 0.." + std::to_string(n - 1));
      edges.emplace_back(a, b);
      edges.emplace_back(b, a);
    }
  const Graph graph = graphFromPairs(std::move(edges), surface_vertices);

  VecX distance = VecX::Constant(n, kInfinity);
  VecXi handles(count);
  int next = first;
  for (int k = 0; k < count; ++k) {
    handles[k] = next;
    chosen[next] = 1;
    // Dijkstra from the new handle, pruned where the old distance is already shorter: the work
    // of the whole sampling stays about one full Dijkstra times a small factor.
    distance[next] = 0;
    MinQueue queue;
    queue.emplace(0.0, next);
    while (!queue.empty()) {
      const auto [d, i] = queue.top();
      queue.pop();
      if (d > distance[i]) continue;
      for (int e = graph.start[i]; e < graph.start[i + 1]; ++e) {
        const int j = graph.neighbour[e];
        const double dj = d + graph.length[e];
        if (dj < distance[j]) {
          distance[j] = dj;
          queue.emplace(dj, j);
        }
      }
    }
    if (k == 0)
      for (int i = 0; i < n; ++i)
        if (distance[i] == kInfinity)
          throw InputError(std::string(who) + ": vertex " + std::to_string(i) +
                           " is not connected to vertex " + std::to_string(first) +
                           " by surface_faces, expected one connected surface");
    if (k + 1 < count) next = farthestUnchosen(distance, chosen);
  }
  return handles;
}

// ---------------------------------------------------------------------------------------------
// Biharmonic energy

namespace {

struct BiharmonicParts {
  SpMat L;  // #N × #N stiffness at the rest nodes, m
  SpMat Q;  // #N × #N, L M⁻¹ L, 1/m
};

BiharmonicParts biharmonicParts(const TetMesh& mesh, const MatX3& rest_nodes, const char* who) {
  detail::checkTetMesh(mesh, rest_nodes, who);
  TetMesh at_rest = mesh;
  at_rest.nodes = rest_nodes;
  const SpMat L = cotangentLaplacian(at_rest);
  const VecX volumes = tetVolumes(at_rest);
  VecX lumped = VecX::Zero(mesh.numNodes());
  for (int t = 0; t < mesh.numTets(); ++t)
    for (int k = 0; k < 4; ++k) lumped[mesh.tets(t, k)] += volumes[t] / 4;
  const SpMat scaled = lumped.cwiseInverse().asDiagonal() * L;
  const SpMat product = L * scaled;
  // Exactly symmetric (the two triangles are summed in different orders).
  SpMat Q = 0.5 * (product + SpMat(product.transpose()));
  Q.makeCompressed();
  return {L, Q};
}

}  // namespace

SpMat biharmonicEnergyMatrix(const TetMesh& mesh, const MatX3& rest_nodes) {
  return biharmonicParts(mesh, rest_nodes, "biharmonicEnergyMatrix").Q;
}

// ---------------------------------------------------------------------------------------------
// Bounded biharmonic weights

namespace {

enum NodeState : signed char { kFree = 0, kAtLower = 1, kAtUpper = 2, kFixed = 3 };

struct HandleResult {
  int iterations = 0;
  double kkt_residual = 0;  // largest KKT violation / the handle's scale
  bool converged = false;
};

/// The QP of one handle: min ½ φᵀQφ subject to the fixed values and 0 ≤ φ ≤ 1 on free nodes.
/// `fixed_state` holds kFixed on handles and bone nodes, kAtLower elsewhere; `initial_free`
/// lists (sorted) the nodes of the first working set.
class HandleSolver {
 public:
  HandleSolver(const SpMat& Q, const std::vector<signed char>& fixed_state, int handle,
               const BoundedBiharmonicOptions& options)
      : Q_(Q), state_(fixed_state), options_(options), n_(int(Q.rows())) {
    x_ = VecX::Zero(n_);
    x_[handle] = 1;
    g_ = Q_.col(handle);  // Q x for x = e_handle
    scale_ = 0;
    for (SpMat::InnerIterator it(Q_, handle); it; ++it)
      scale_ = std::max(scale_, std::abs(it.value()));
    tolerance_ = options.kkt_tolerance * scale_;
    position_.assign(n_, -1);
  }

  HandleResult solve(const std::vector<int>& initial_free) {
    for (int i : initial_free) state_[i] = kFree;
    HandleResult result;
    while (result.iterations < options_.max_iterations) {
      collectWorkingSet();
      bool at_face_minimum = working_.empty();
      if (!at_face_minimum) {
        ++result.iterations;
        at_face_minimum = faceStep();
      }
      // Released bounds join the next face at once (the face direction still descends: their
      // multipliers say the energy falls as they leave the bound).
      const int released = releaseWrongMultipliers();
      if (at_face_minimum && released == 0) {
        result.converged = true;
        break;
      }
    }
    refreshGradient();
    result.kkt_residual = kktViolation() / scale_;
    result.converged = result.converged && result.kkt_residual <= options_.kkt_tolerance;
    return result;
  }

  const VecX& weights() const { return x_; }

 private:
  void collectWorkingSet() {
    for (int i : working_) position_[i] = -1;
    working_.clear();
    for (int i = 0; i < n_; ++i)
      if (state_[i] == kFree) {
        position_[i] = int(working_.size());
        working_.push_back(i);
      }
  }

  /// Q restricted to the working set (full symmetric storage, rows sorted).
  SpMat faceMatrix() const {
    const int m = int(working_.size());
    SpMat A(m, m);
    std::vector<int> outer(m + 1, 0);
    std::vector<int> inner;
    std::vector<double> values;
    for (int c = 0; c < m; ++c) {
      for (SpMat::InnerIterator it(Q_, working_[c]); it; ++it) {
        const int r = position_[it.row()];
        if (r < 0) continue;
        inner.push_back(r);
        values.push_back(it.value());
      }
      outer[c + 1] = int(inner.size());
    }
    A.resizeNonZeros(Eigen::Index(inner.size()));
    std::copy(outer.begin(), outer.end(), A.outerIndexPtr());
    std::copy(inner.begin(), inner.end(), A.innerIndexPtr());
    std::copy(values.begin(), values.end(), A.valuePtr());
    return A;
  }

  /// One minimization on the face of the working set followed by a projected search. Returns
  /// true when the face minimizer itself was feasible and taken (the working set is optimal on
  /// its face); otherwise the bounds met were added to the active set.
  bool faceStep() {
    const int m = int(working_.size());
    const SpMat A = faceMatrix();
    const Eigen::SimplicialLLT<SpMat, Eigen::Lower, Eigen::AMDOrdering<int>> cholesky(A);
    if (cholesky.info() != Eigen::Success)
      throw Error("computeBoundedBiharmonicWeights: the face matrix of " + std::to_string(m) +
                  " nodes is not positive definite (is a free node cut off from every handle "
                  "and bone node?)");
    VecX gradient(m), current(m);
    for (int k = 0; k < m; ++k) {
      gradient[k] = g_[working_[k]];
      current[k] = x_[working_[k]];
    }
    const VecX direction = -cholesky.solve(gradient);
    const VecX minimizer = current + direction;
    if (minimizer.minCoeff() >= 0 && minimizer.maxCoeff() <= 1) {
      applyStep(direction, false);
      return true;
    }
    // Projected search along P(x + α d): sufficient decrease against the first-order change.
    for (double alpha = 1; alpha > std::ldexp(1.0, -kMaxHalvings); alpha *= 0.5) {
      const VecX step = (current + alpha * direction).cwiseMax(0.0).cwiseMin(1.0) - current;
      if (sufficientDecrease(A, gradient, step)) {
        applyStep(step, true);
        return false;
      }
    }
    // Degenerate start (every working node on a bound, the face direction pointing out): a
    // projected-gradient step, which decreases the energy whenever the projected gradient is
    // not zero.
    const double curvature = gradient.dot(A * gradient);
    double alpha = curvature > 0 ? gradient.squaredNorm() / curvature : 1;
    for (int halving = 0; halving < kMaxHalvings; ++halving, alpha *= 0.5) {
      const VecX step = (current - alpha * gradient).cwiseMax(0.0).cwiseMin(1.0) - current;
      if (step.lpNorm<Eigen::Infinity>() == 0) break;
      if (sufficientDecrease(A, gradient, step)) {
        applyStep(step, true);
        return false;
      }
    }
    // No descent along either path: the working nodes on a bound stay there.
    applyStep(VecX::Zero(m), true);
    return true;
  }

  bool sufficientDecrease(const SpMat& A, const VecX& gradient, const VecX& step) const {
    const double first_order = gradient.dot(step);
    if (!(first_order < 0)) return false;
    const double change = first_order + 0.5 * step.dot(A * step);
    return change <= kArmijo * first_order;
  }

  /// x += step on the working set, g += Q step; with `classify`, working nodes that reached a
  /// bound join the active set.
  void applyStep(const VecX& step, bool classify) {
    for (int k = 0; k < int(working_.size()); ++k) {
      const int i = working_[k];
      if (step[k] != 0) {
        for (SpMat::InnerIterator it(Q_, i); it; ++it) g_[it.row()] += it.value() * step[k];
        x_[i] += step[k];
      }
      if (classify) {
        x_[i] = std::clamp(x_[i], 0.0, 1.0);
        if (x_[i] == 0)
          state_[i] = kAtLower;
        else if (x_[i] == 1)
          state_[i] = kAtUpper;
      }
    }
  }

  /// Frees every bound whose multiplier has the wrong sign beyond the tolerance; returns how many.
  int releaseWrongMultipliers() {
    int released = 0;
    for (int i = 0; i < n_; ++i) {
      if ((state_[i] == kAtLower && g_[i] < -tolerance_) ||
          (state_[i] == kAtUpper && g_[i] > tolerance_)) {
        state_[i] = kFree;
        ++released;
      }
    }
    return released;
  }

  void refreshGradient() { g_ = Q_ * x_; }

  double kktViolation() const {
    double worst = 0;
    for (int i = 0; i < n_; ++i) {
      switch (state_[i]) {
        case kFree:
          worst = std::max(worst, std::abs(g_[i]));
          break;
        case kAtLower:
          worst = std::max(worst, -g_[i]);
          break;
        case kAtUpper:
          worst = std::max(worst, g_[i]);
          break;
        default:
          break;
      }
    }
    return worst;
  }

  const SpMat& Q_;
  std::vector<signed char> state_;
  const BoundedBiharmonicOptions& options_;
  const int n_;
  VecX x_, g_;
  double scale_ = 1, tolerance_ = 0;
  std::vector<int> working_, position_;
};

/// Free nodes within options.initial_radius_factor × (distance to the nearest other handle)
/// of `handle` along tet edges through soft nodes, sorted.
std::vector<int> initialNeighbourhood(const Graph& graph, const std::vector<signed char>& state,
                                      const std::vector<char>& is_handle,
                                      const std::vector<char>& is_bone, int handle,
                                      double radius_factor) {
  const int n = int(state.size());
  std::vector<double> distance(n, kInfinity);
  std::vector<int> nodes;
  double radius = kInfinity;
  distance[handle] = 0;
  MinQueue queue;
  queue.emplace(0.0, handle);
  while (!queue.empty()) {
    const auto [d, i] = queue.top();
    queue.pop();
    if (d > distance[i]) continue;
    if (d > radius) break;
    if (i != handle && is_handle[i] && radius == kInfinity) radius = radius_factor * d;
    if (state[i] != kFixed) nodes.push_back(i);
    if (is_bone[i]) continue;
    for (int e = graph.start[i]; e < graph.start[i + 1]; ++e) {
      const int j = graph.neighbour[e];
      const double dj = d + graph.length[e];
      if (dj < distance[j]) {
        distance[j] = dj;
        queue.emplace(dj, j);
      }
    }
  }
  std::sort(nodes.begin(), nodes.end());
  return nodes;
}

}  // namespace

BoundedBiharmonicWeights computeBoundedBiharmonicWeights(const TetMesh& mesh,
                                                         const MatX3& rest_nodes,
                                                         const VecXi& handles,
                                                         const VecXi& bone_of_node,
                                                         const BoundedBiharmonicOptions& options) {
  const auto started = std::chrono::steady_clock::now();
  const std::string fn = "computeBoundedBiharmonicWeights: ";
  detail::checkTetMesh(mesh, rest_nodes, "computeBoundedBiharmonicWeights");
  const int n = mesh.numNodes();
  if (bone_of_node.size() != n)
    throw InputError(fn + "bone_of_node has " + std::to_string(bone_of_node.size()) +
                     " entries, expected #N = " + std::to_string(n));
  if (handles.size() == 0) throw InputError(fn + "handles is empty, expected at least 1 handle");
  if (!(options.kkt_tolerance > 0) || options.max_iterations < 1 ||
      !(options.initial_radius_factor > 0) || options.threads < 0)
    throw InputError(fn +
                     "options: expected kkt_tolerance > 0, max_iterations ≥ 1, "
                     "initial_radius_factor > 0, threads ≥ 0");
  std::vector<char> is_bone(n, 0), is_handle(n, 0);
  for (int i = 0; i < n; ++i) {
    if (bone_of_node[i] < -1)
      throw InputError(fn + "bone_of_node[" + std::to_string(i) + "] = " +
                       std::to_string(bone_of_node[i]) + ", expected −1 (soft) or a bone ≥ 0");
    is_bone[i] = bone_of_node[i] >= 0;
  }
  for (int h = 0; h < handles.size(); ++h) {
    const int i = handles[h];
    if (i < 0 || i >= n)
      throw InputError(fn + "handles[" + std::to_string(h) + "] = " + std::to_string(i) +
                       ", expected a node index in 0.." + std::to_string(n - 1));
    if (is_handle[i])
      throw InputError(fn + "handles[" + std::to_string(h) + "] = " + std::to_string(i) +
                       " is repeated, expected distinct nodes");
    if (is_bone[i])
      throw InputError(fn + "handles[" + std::to_string(h) + "] = " + std::to_string(i) +
                       " is a bone node (bone_of_node = " + std::to_string(bone_of_node[i]) +
                       "), expected a soft-tissue node");
    is_handle[i] = 1;
  }

  const BiharmonicParts parts =
      biharmonicParts(mesh, rest_nodes, "computeBoundedBiharmonicWeights");
  const SpMat& Q = parts.Q;
  const SpMat& L = parts.L;
  std::vector<std::pair<int, int>> edges;
  edges.reserve(size_t(L.nonZeros()));
  for (int j = 0; j < L.outerSize(); ++j)
    for (SpMat::InnerIterator it(L, j); it; ++it)
      if (it.row() != j) edges.emplace_back(int(it.row()), j);
  const Graph graph = graphFromPairs(std::move(edges), rest_nodes);

  std::vector<signed char> fixed_state(n, kAtLower);
  for (int i = 0; i < n; ++i)
    if (is_bone[i] || is_handle[i]) fixed_state[i] = kFixed;

  const int H = int(handles.size());
  BoundedBiharmonicWeights out;
  out.weights = MatX::Zero(n, H);
  out.report.iterations = VecXi::Zero(H);
  out.report.support_size = VecXi::Zero(H);
  std::vector<HandleResult> results(H);
  std::string failure;
  bool failed = false;
  const int threads = options.threads > 0 ? options.threads : omp_get_max_threads();
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads)
  for (int h = 0; h < H; ++h) {
    try {
      const std::vector<int> start = initialNeighbourhood(
          graph, fixed_state, is_handle, is_bone, handles[h], options.initial_radius_factor);
      HandleSolver solver(Q, fixed_state, handles[h], options);
      results[h] = solver.solve(start);
      out.weights.col(h) = solver.weights();
    } catch (const std::exception& e) {
#pragma omp critical(flsh_bbw_failure)
      if (!failed) {
        failed = true;
        failure = e.what();
      }
    }
  }
  if (failed) throw Error(failure);

  BoundedBiharmonicReport& report = out.report;
  for (int h = 0; h < H; ++h) {
    report.iterations[h] = results[h].iterations;
    report.converged = report.converged && results[h].converged;
    report.max_kkt_residual = std::max(report.max_kkt_residual, results[h].kkt_residual);
    const auto column = out.weights.col(h);
    for (int i = 0; i < n; ++i) {
      if (fixed_state[i] == kFixed) {
        const double target = i == handles[h] ? 1.0 : 0.0;
        report.max_constraint_error =
            std::max(report.max_constraint_error, std::abs(column[i] - target));
      } else {
        report.max_bound_violation =
            std::max({report.max_bound_violation, -column[i], column[i] - 1});
        if (column[i] > 0) ++report.support_size[h];
      }
    }
  }
  report.seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  return out;
}

}  // namespace flsh
