// Triangle mesh of an implicit surface with an exact vertex count (internal to the synthetic
// body generator).
//
// Pipeline: marching tetrahedra on a regular grid (Kuhn split of each cube, so neighbouring
// cells agree and the result is a closed manifold), shortest-edge-first edge collapse with
// the link condition down to exactly `vertices` vertices (a closed genus-0 mesh keeps its
// topology), then a few rounds of Delaunay edge flips and tangential relaxation with
// projection back onto the surface. Deterministic: no randomness, no threads.
#pragma once

#include <functional>

#include "flsh/core/types.h"

namespace flsh::synthetic {

struct ImplicitSurface {
  /// Signed distance (or a Lipschitz-2 bound of it), m: negative inside, positive outside.
  std::function<double(const Vec3&)> value;
  /// Relative target edge length (1 = the mesh's average, < 1 = denser), for grading.
  std::function<double(const Vec3&)> relative_edge_length;
  /// Box that contains the whole surface with some margin, m.
  Vec3 box_min = Vec3::Zero();
  Vec3 box_max = Vec3::Zero();
};

struct MesherOptions {
  /// Exact number of output vertices.
  int vertices = 1000;
  /// Grid spacing of marching tetrahedra, m (the finest feature must span ≥ 2 cells).
  double grid_spacing = 0.01;
  /// Rounds of (Delaunay flips, tangential relaxation, projection) after decimation.
  int relax_rounds = 6;
};

struct TriangleMesh {
  MatX3 vertices;  // #V × 3, m
  MatX3i faces;    // #F × 3, counter-clockwise seen from outside
};

/// Meshes the surface {value = 0}. Throws flsh::Error when the surface is not a single closed
/// genus-0 component or when the requested count cannot be reached.
TriangleMesh meshImplicitSurface(const ImplicitSurface& surface, const MesherOptions& options);

/// Moves p onto {value = 0} by Newton steps along the central-difference gradient.
Vec3 projectOntoSurface(const ImplicitSurface& surface, const Vec3& p, int max_steps = 4);

}  // namespace flsh::synthetic
