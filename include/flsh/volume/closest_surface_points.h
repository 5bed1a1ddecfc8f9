// Closest points of a triangle surface to many query points (exact, through a bounding-box tree):
// the search behind fits to unordered scan points (flsh.torch.point_to_surface), which then
// differentiate the distance with the barycentric coordinates held.
#pragma once

#include "flsh/core/types.h"

namespace flsh {

/// Per query point: the closest surface point's triangle, its barycentric coordinates on that
/// triangle's three vertices (≥ 0, sum 1) and the distance.
struct ClosestSurfacePoints {
  VecXi faces;        ///< #P rows of F
  MatX3 barycentric;  ///< #P × 3
  VecX distances;     ///< #P, m
};

/// V: #V × 3 vertices, F: #F × 3 triangles (at least one; indices into V), points: #P × 3, all
/// finite. Deterministic (ties go to the triangle the tree visits first); points in parallel.
/// Throws InputError naming the argument on a bad shape, index or value.
ClosestSurfacePoints closestSurfacePoints(const MatX3& V, const MatX3i& F, const MatX3& points);

}  // namespace flsh
