// The linear reduced basis of the ROM soft skeleton (ARCHITECTURE.md §4): soft-tissue
// displacement u(X̄) = Σ_h φ_h(X̄) z_h, with point handles on the body surface chosen by
// farthest-point sampling and φ_h bounded biharmonic weights on the tet mesh.
//
// Bounded biharmonic weights (Jacobson et al. 2011, with zero Dirichlet data on bone nodes): for
// each handle h, φ_h minimizes the biharmonic energy φᵀ Q φ, Q = L M⁻¹ L (L the P1 stiffness
// matrix of cotangentLaplacian, M the lumped node volumes), subject to φ_h = 1 at its handle,
// φ_h = 0 at the other handles and on bone nodes, and 0 ≤ φ_h ≤ 1 on the remaining (free) nodes.
// The bounds are handled by a bound-constrained QP solver, not by clamping. The weights are NOT
// renormalized: with zero data on bone nodes they do not sum to 1 (they fade to 0 towards bone).
#pragma once

#include "flsh/core/types.h"
#include "flsh/volume/tet_mesh.h"

namespace flsh {

/// Deterministic Euclidean farthest-point sampling: starts at `first`, then repeatedly adds the
/// vertex farthest (straight-line distance) from those chosen; ties go to the lower index.
/// Returns `count` distinct vertex indices in selection order. surface_vertices: #V × 3 (m).
/// bone_of_vertex: empty, or #V entries as VecXi bone_of_node's first V rows: vertices with an
/// entry ≥ 0 (surface nodes attached to a bone, e.g. on the hands) are never chosen, since a
/// handle must be a soft-tissue node. Throws InputError on count < 1 or > the number of eligible
/// vertices, `first` outside [0, #V) or not eligible, non-finite vertices, or a bone_of_vertex
/// of another length.
VecXi farthestPointSurfaceHandles(const MatX3& surface_vertices, int count, int first = 0,
                                  const VecXi& bone_of_vertex = VecXi());

/// Geodesic variant: distances are shortest paths along the edges of the triangle mesh
/// (surface_faces: #F × 3), so that two surface sheets that are close in space but far apart on
/// the body (inner thighs, arm and flank) do not shadow each other; paths may cross ineligible
/// vertices. Same rules and errors as the Euclidean version, plus InputError for face indices out
/// of range and for vertices that no path reaches from `first` (a disconnected surface).
VecXi farthestPointSurfaceHandles(const MatX3& surface_vertices, const MatX3i& surface_faces,
                                  int count, int first = 0, const VecXi& bone_of_vertex = VecXi());

/// Biharmonic energy matrix Q = L M⁻¹ L (#N × #N, symmetric positive semi-definite, units 1/m):
/// L = cotangentLaplacian of the mesh with its nodes replaced by rest_nodes (#N × 3, m), M the
/// lumped node volumes (a quarter of each incident tet's volume, m³). Throws InputError for a
/// rest_nodes of the wrong shape or an invalid mesh (see cotangentLaplacian).
SpMat biharmonicEnergyMatrix(const TetMesh& mesh, const MatX3& rest_nodes);

struct BoundedBiharmonicOptions {
  /// KKT tolerance, relative to the largest |Q_hj| in the handle's column: the solve of a handle
  /// stops when the gradient g = Qφ (of ½φᵀQφ) is within tol of 0 on nodes strictly inside the
  /// bounds, g ≥ −tol on nodes at the bound 0 and g ≤ tol on nodes at the bound 1. A node left
  /// at 0 with g = −tol would rise by about tol/Q_ii if freed, so the default bounds the error of
  /// the weights near 1e-6 while cutting off the (then tiny) far tail that would otherwise take
  /// many more iterations (measured on the default body: 1e-6 → 10 face solves per handle on
  /// average, 1e-8 → 16 and twice the support).
  double kkt_tolerance = 1e-6;
  /// Face solves (subspace minimizations) per handle before giving up (report.converged false).
  int max_iterations = 400;
  /// The first working set of a handle: the free nodes within this many times the distance to
  /// the nearest other handle (along tet edges); every other free node starts on the bound 0.
  /// Only the speed depends on it: the solver releases nodes whose multipliers say so.
  double initial_radius_factor = 1.5;
  /// OpenMP threads across handles; 0: OpenMP's default.
  int threads = 0;
};

/// What the solve did; the bound and constraint figures are measured on the returned weights.
struct BoundedBiharmonicReport {
  double max_bound_violation = 0;   ///< max over free nodes of max(−φ, φ − 1, 0)
  double max_constraint_error = 0;  ///< max |φ_h − δ| at the handles and |φ_h| on bone nodes
  double max_kkt_residual = 0;      ///< largest KKT violation / the handle's tolerance scale
  VecXi iterations;                 ///< H: face solves per handle
  VecXi support_size;               ///< H: free nodes with φ_h > 0 per handle
  bool converged = true;            ///< every handle met the KKT tolerance
  double seconds = 0;               ///< wall clock of the whole computation
};

struct BoundedBiharmonicWeights {
  MatX weights;  ///< #N × H, column h = φ_h at every node (dimensionless, in [0, 1])
  BoundedBiharmonicReport report;
};

/// Bounded biharmonic weights of `handles` (H node indices, distinct, soft-tissue nodes) on the
/// tet mesh at rest_nodes (#N × 3, m). bone_of_node (#N) follows VolumetricData::bone_of_node:
/// −1 for a soft-tissue node, ≥ 0 for a bone node (held at 0 in every φ_h).
///
/// Each handle's QP is solved by a primal active-set method with projected searches (after Moré &
/// Toraldo 1991, with direct sparse Cholesky face solves): from a feasible point, minimize on the
/// face of the working set, move along the projected path P(x + α d) with a sufficient-decrease
/// search (every bound met joins the active set, in one batch), then release every active bound
/// whose multiplier has the wrong sign. Every step lowers the energy (the face direction descends
/// even with the released bounds; a projected-gradient step backs up a failed search), so no
/// working set repeats; it stops at a face minimizer with no wrong-sign multiplier (KKT).
/// Locality: the first working set is a neighbourhood of the handle, all other free nodes start
/// on the bound 0; optimality is then checked on every node. Handles run in parallel (OpenMP).
/// Deterministic (each handle's solve does not depend on the thread schedule).
/// Throws InputError for shapes or values that do not fit (handle out of range, repeated, or on
/// a bone node; bone_of_node entries < −1; no handle) naming the argument.
BoundedBiharmonicWeights computeBoundedBiharmonicWeights(
    const TetMesh& mesh, const MatX3& rest_nodes, const VecXi& handles, const VecXi& bone_of_node,
    const BoundedBiharmonicOptions& options = {});

}  // namespace flsh
