// The CGAL stages of tetrahedralizeSurface (include/flsh/volume/tet_mesh.h). Only
// src/cgal/*.cpp include CGAL; this interface uses Eigen types and reports failures as data so
// that the orchestration, error messages and validation stay in src/volume/tet_mesh.cpp (which
// links against this target, never the other way round).
#pragma once

#include <array>
#include <utility>

#include "flsh/core/types.h"

namespace flsh::cgal {

/// Interior points of the closed polyhedron (V: #V × 3, m; F: #F × 3, outward) from CGAL Mesh_3
/// with cells of circumradius ≤ cell_size (m). A Mesh_3 vertex is kept only if it lies strictly
/// inside and at least clearance × (mean edge length of the nearest surface triangle) away from
/// the surface, so that it cannot take the place of a surface face in the Delaunay
/// tetrahedralization. Sorted lexicographically (#P × 3). Deterministic in `seed`.
MatX3 meshInteriorPoints(const MatX3& V, const MatX3i& F, double cell_size, double clearance,
                         unsigned seed);

/// The first pair of faces (row indices of F) that intersect other than along shared vertices
/// or edges, or {−1, −1} for a surface without self-intersections. F must be a closed manifold.
std::pair<int, int> firstSelfIntersection(const MatX3& V, const MatX3i& F);

struct BoundaryConformingTets {
  MatX4i tets;               ///< #T × 4 inside tets, positively oriented (empty if any failure)
  int missing_faces = 0;     ///< faces of F absent from the Delaunay tetrahedralization
  int recovered_faces = 0;   ///< of those, recovered by flips
  int unrecovered_faces = 0; ///< of those, still absent (then `tets` is empty)
  int example_unrecovered = -1;  ///< row of F of one unrecovered face
  double delaunay_seconds = 0, recovery_seconds = 0;
};

/// Delaunay tetrahedralization of `nodes` (#N × 3; rows 0..V−1 are the surface vertices that F
/// indexes), boundary recovery of every face of F by 2–3 and 3–2 flips (no point is added), and
/// the tets enclosed by F (flood fill from outside, stopped by the faces of F).
BoundaryConformingTets boundaryConformingTets(const MatX3& nodes, const MatX3i& F);

}  // namespace flsh::cgal
