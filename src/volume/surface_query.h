// Internals of the volumetric fields and materials (not public API): the outward boundary
// triangles of a tet mesh, and closest-point queries on a triangle surface through a static
// bounding-box tree (no CGAL: CGAL stays in src/cgal/).
#pragma once

#include <Eigen/Geometry>
#include <vector>

#include "flsh/core/types.h"
#include "flsh/volume/tet_mesh.h"

namespace flsh::detail {

/// Throws InputError (prefixed by `who`) unless the mesh is usable by the field and material
/// code: nodes finite, 0 ≤ num_surface_nodes ≤ #N, tet indices in range and distinct, every node
/// used by some tet and, when require_positive_volume, every tet positively oriented at `nodes`.
/// Geometric queries on shaped nodes skip the orientation test: a body shape X̄₀ + S β may
/// invert a few slivers, which is for the simulation to report, not for a distance query.
void checkTetMesh(const TetMesh& mesh, const MatX3& nodes, const char* who,
                  bool require_positive_volume = true);

/// Faces of exactly one tet (#B × 3), counter-clockwise seen from outside, in tet order; the tet
/// owning each face in `owners` (#B) when not null. Throws InputError (prefixed by `who`) if a
/// face belongs to more than two tets or a boundary face uses a node ≥ num_surface_nodes (the
/// surface must be nodes 0..V−1).
MatX3i outwardBoundaryFaces(const TetMesh& mesh, const char* who,
                            std::vector<int>* owners = nullptr);

/// Area-weighted vertex normals (#V × 3, unit; zero rows for vertices no face uses).
MatX3 vertexNormals(const MatX3& V, const MatX3i& F);

/// The closest point of a triangle surface to query points.
class SurfaceDistance {
 public:
  struct Hit {
    double distance = 0;              ///< m
    Vec3 point = Vec3::Zero();        ///< closest surface point
    int face = -1;                    ///< its triangle (row of F)
    Vec3 barycentric = Vec3::Zero();  ///< its weights on F(face, 0..2), sum 1, ≥ 0
  };
  /// V: #V × 3, F: #F × 3 (at least one face). Both are copied.
  SurfaceDistance(const MatX3& V, const MatX3i& F);
  /// Deterministic: ties between triangles go to the one visited first (fixed tree order).
  Hit closest(const Vec3& x) const;

 private:
  struct Node {
    Eigen::AlignedBox3d box;
    int left = -1, right = -1;  ///< children (inner node) or −1 (leaf)
    int begin = 0, end = 0;     ///< leaf triangles: order_[begin, end)
  };
  int build(int begin, int end);
  MatX3 V_;
  MatX3i F_;
  std::vector<int> order_;
  std::vector<Node> nodes_;
};

}  // namespace flsh::detail
