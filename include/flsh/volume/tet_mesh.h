// The tetrahedral mesh of a closed body surface (ARCHITECTURE.md §3): the surface vertices are
// nodes 0..V−1 in input order and the surface triangles are exactly the boundary faces, so that
// every body shape X̄(β) = X̄₀ + S β reuses one discretization. Built with CGAL (src/cgal/), but
// this header exposes Eigen types only.
#pragma once

#include "flsh/core/types.h"

namespace flsh {

struct TetMeshOptions {
  /// Interior node density relative to the default: 1 gives about 0.45·V interior nodes (≈10 000
  /// nodes in all for a 6890-vertex SMPL body, ≈45 000 tets); 2 twice as many, 0.5 half.
  /// Must be finite and in [0.01, 100].
  double resolution = 1.0;
  /// Seed of the random generator of the interior mesher; the same seed and input give the same
  /// bytes.
  unsigned seed = 1;
  /// Run improveTetMeshQuality on the result (flips and interior-node moves that raise the
  /// worst dihedral angles; the surface nodes and boundary faces are unchanged either way).
  bool improve_quality = true;
};

struct TetMesh {
  MatX3 nodes;  ///< #N × 3, m; nodes 0..V−1 are the surface vertices in input order
  MatX4i tets;  ///< #T × 4, positively oriented: ((x1−x0)×(x2−x0))·(x3−x0) > 0
  int num_surface_nodes = 0;  ///< V
  int numNodes() const { return int(nodes.rows()); }
  int numTets() const { return int(tets.rows()); }
};

struct TetMeshQuality {
  double min_dihedral_deg = 0, max_dihedral_deg = 0;             ///< over all tets, degrees
  double max_radius_edge_ratio = 0, mean_radius_edge_ratio = 0;  ///< circumradius / shortest edge
  double min_volume = 0;                                         ///< m³
};

/// Wall-clock seconds of the stages of tetrahedralizeSurface, and how many surface faces were
/// missing from the Delaunay tetrahedralization and recovered by flips.
struct TetMeshTimings {
  double interior_points = 0, delaunay = 0, recovery = 0, quality = 0, total = 0;
  int recovered_faces = 0;
};

/// Tetrahedralizes the closed, manifold, consistently outward-oriented surface (V: #V × 3, m;
/// F: #F × 3) without adding surface points: the boundary faces of the result are F exactly (as
/// oriented triangles). Interior nodes come from CGAL Mesh_3 at a size set by the enclosed volume
/// and options.resolution; then, if options.improve_quality, improveTetMeshQuality (the interior
/// nodes move). Throws InputError for a bad surface (non-finite or coincident vertices,
/// out-of-range or repeated indices, unreferenced vertices, open or non-manifold edges or
/// vertices, inward orientation, self-intersections) and Error if a surface face cannot be
/// recovered (naming how many and one of them). Never returns a mesh that fails validateTetMesh.
TetMesh tetrahedralizeSurface(const MatX3& V, const MatX3i& F, const TetMeshOptions& options = {},
                              TetMeshTimings* timings = nullptr);

/// What improveTetMeshQuality did. The quality of a tet is the smallest sine of its six dihedral
/// angles (0 for a flat tet, sin 70.53° ≈ 0.943 for the regular one): small for both too-small
/// and too-large angles.
struct TetMeshImprovement {
  int rounds = 0;         ///< flip + move rounds run
  int face_flips = 0;     ///< 2–3 flips (a face between two tets replaced by an edge)
  int edge_removals = 0;  ///< edges removed (3–2, 4–4 and n–(2n−4) flips)
  int node_moves = 0;     ///< accepted moves of interior nodes
  double min_sine_before = 0, min_sine_after = 0;  ///< worst tet quality over the mesh
};

/// Raises the quality of the worst tets of a valid tet mesh in place, without touching its
/// surface: surface nodes (0..num_surface_nodes−1) and nodes on boundary faces never move,
/// boundary faces are never flipped, no node is added or removed, and the node rows keep their
/// order. Rounds of (1) flips around the tets with a dihedral angle under 20° or over 160° —
/// 2–3 face flips and edge removals (the edge's ring retriangulated by dynamic programming) —
/// and (2) moves of their interior nodes (to the neighbours' centroid, then ascent steps on the
/// worst incident dihedral sine, with a line search); an operation is accepted only if it raises
/// the worst quality among the tets it replaces or moves, so the mesh's worst tet never gets
/// worse and no tet inverts, and only if no tet it creates has a radius–edge ratio above 2.5 or
/// above the worst ratio among the tets it replaces. Tets come out in the canonical order of
/// tetrahedralizeSurface (their number usually drops: 3–2 flips). Deterministic; about 0.1 s for
/// a 40 000-tet body. Throws InputError if a tet has out-of-range or repeated indices or volume
/// ≤ 0, or num_surface_nodes is outside [0, #N].
TetMeshImprovement improveTetMeshQuality(TetMesh& mesh);

/// Dihedral angles, radius–edge ratios and the smallest volume over all tets.
TetMeshQuality tetMeshQuality(const TetMesh& mesh);

/// Throws Error describing the first violation: a tet with out-of-range or repeated indices, an
/// inverted or degenerate (volume ≤ 0) tet, boundary faces ≠ F (as oriented triangles), a surface
/// node that no face of F uses, or a node that no tet uses.
void validateTetMesh(const TetMesh& mesh, const MatX3i& F);

/// Per-tet signed volumes (#T), m³.
VecX tetVolumes(const TetMesh& mesh);

/// The faces that belong to exactly one tet (#B × 3), oriented outward (counter-clockwise seen
/// from outside), in a canonical order: each row rotated to start at its smallest index, rows
/// sorted. A face shared by more than two tets makes the mesh non-manifold: throws Error.
MatX3i boundaryFaces(const MatX4i& tets);

}  // namespace flsh
