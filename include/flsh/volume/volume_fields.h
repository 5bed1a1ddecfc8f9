// Fields of the volumetric body on the tet mesh (ARCHITECTURE.md §3): the P1 Laplacian, the
// harmonic extension of surface data to the interior nodes, the body's skinning weights, shape
// directions and pose blend shapes on every node, the rest nodes of a body shape, and the bone
// nodes (interior nodes deep enough to move rigidly with the skeleton).
//
// Node layout (TetMesh): nodes 0..V−1 are the body's surface vertices in SMPL order; nodes
// V..N−1 are interior. Per-node vector fields use BodyModel's row layout: row 3i + c is
// coordinate c of node i.
#pragma once

#include <memory>
#include <vector>

#include "flsh/body/body_model.h"
#include "flsh/core/types.h"
#include "flsh/volume/tet_mesh.h"

namespace flsh {

/// P1 stiffness matrix K_ij = Σ_T vol_T ∇φ_i·∇φ_j (the "cotangent Laplacian on tets"): #N × #N,
/// symmetric positive semi-definite, rows sum to 0, units m. Throws InputError for an invalid
/// mesh (indices out of range or repeated, a tet with volume ≤ 0, a node in no tet).
SpMat cotangentLaplacian(const TetMesh& mesh);

/// Harmonic extension with the surface nodes 0..V−1 as Dirichlet data: solves K_II X_I =
/// −K_IB X_B for the interior nodes I = V..N−1. The interior block is factored once (CHOLMOD
/// supernodal Cholesky) in the constructor; extend() solves all columns of its argument in
/// blocks. Linear precision: an affine function of the node positions is reproduced exactly
/// (to rounding). Cheap to copy (the factor is shared); extend() is thread-safe.
class HarmonicExtension {
 public:
  /// Throws InputError for an invalid mesh (see cotangentLaplacian) and Error if the interior
  /// block cannot be factored.
  explicit HarmonicExtension(const TetMesh& mesh);
  /// V × k surface values → N × k values on all nodes; rows 0..V−1 are the input, bit for bit.
  /// Throws InputError if surface_values has ≠ V rows or non-finite entries.
  MatX extend(const MatX& surface_values) const;

  int numNodes() const;         ///< N
  int numSurfaceNodes() const;  ///< V

 private:
  struct Factor;
  std::shared_ptr<const Factor> factor_;
};

/// The body's per-vertex fields extended to all N nodes.
struct InteriorFields {
  /// #N × 24 skinning weights: ≥ 0, rows sum to 1 (interior rows clamped at 0 and renormalized;
  /// surface rows are the body's exactly).
  MatX weights;
  /// 3#N × K shape directions (row 3i + c, m per unit β); surface rows = body.shapedirs.
  MatX shapedirs;
  /// 3#N × 207 pose blend shapes (row 3i + c; column layout as BodyModel::posedirs);
  /// surface rows = body.posedirs.
  MatX posedirs;
};

/// Extends body.weights, body.shapedirs and body.posedirs to the interior nodes with one blocked
/// harmonic solve. The mesh's surface nodes must be the body's template vertices (count, and
/// positions within 1e-6 m), and `harmonic` must have been built on `mesh`; otherwise throws
/// InputError naming what differs.
InteriorFields extendBodyFields(const TetMesh& mesh, const BodyModel& body,
                                const HarmonicExtension& harmonic);

/// Rest nodes of body shape β (#N × 3, m): X̄(β) = X̄₀ + S β with X̄₀ = mesh.nodes and S =
/// fields.shapedirs. On the surface this is the SMPL shaped T-pose v_template + shapedirs β.
/// β may be shorter than K (zero padded), not longer; throws InputError on sizes / non-finite β.
MatX3 shapedNodes(const TetMesh& mesh, const InteriorFields& fields, const VecX& betas);

/// Bone nodes (#N): result[i] = b when node i is interior and its distance to the surface of
/// `shaped_nodes` (the tet mesh's boundary) exceeds the local soft-tissue thickness, i.e.
/// surface_tissue_thickness interpolated at the nearest surface point; −1 otherwise (soft
/// tissue). The attached bone b is the node's largest weight; exact ties go to the bone whose
/// segment (joint to child joints) is nearest, then to the lower index. Anchors: a bone with
/// fewer such deep nodes than max(4, 5 %) of the nodes it dominates also gets its dominated
/// nodes nearest to its segment (interior ones first, then surface ones) — thin parts (hands,
/// forearms) of coarse meshes, whose tissue would otherwise hang on soft tissue alone.
/// Deterministic. Among the deep nodes, monotone in depth: at one nearest surface point, a
/// deeper node is bone whenever a shallower one is. Tets inverted by the shape are accepted (a
/// distance query).
///   shaped_nodes: #N × 3 (m), weights: #N × B, joints: B × 3 (m), parents: B (parents[0] = −1),
///   surface_tissue_thickness: V (m, ≥ 0).
/// Throws InputError naming the argument with the wrong shape or value.
VecXi selectBoneNodes(const TetMesh& mesh, const MatX3& shaped_nodes, const MatX& weights,
                      const MatX3& joints, const std::vector<int>& parents,
                      const VecX& surface_tissue_thickness);

/// Distance of every node of `shaped_nodes` (#N × 3) to the boundary surface of the tet mesh
/// (#N, m; 0 on the surface nodes). Throws InputError for an invalid mesh (inverted tets are
/// accepted).
VecX nodeDepths(const TetMesh& mesh, const MatX3& shaped_nodes);

}  // namespace flsh
