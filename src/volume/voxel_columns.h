// The column grid on which computeBoneInertia voxelizes a surface (internal; exposed to tests so
// they can place vertices exactly on columns).
#pragma once

#include <cmath>

#include "flsh/core/types.h"

namespace flsh::voxel {

// Column centres sit at x_i = x_min + (i + ½ − δ) h: half a voxel in from the bounding box, as
// if voxels tiled it from its corner, less a small fixed irrational fraction δ (of √2, √3, √5)
// so that vertices on round coordinates (boxes, grids) never fall exactly on a column. Small, so
// a box whose edges are multiples of h is still covered by exactly its voxels.
constexpr double kJitterX = 0.0414213562373095;
constexpr double kJitterY = 0.0732050807568877;
constexpr double kJitterZ = 0.0236067977499790;

/// Vertical columns (along z) at voxel centres (x_i, y_j), i < nx, j < ny, and voxel layers
/// bounded by z_k = origin_z + k h; covers the bounding box of the surface.
struct ColumnGrid {
  double origin_x = 0, origin_y = 0, origin_z = 0;  ///< m
  double h = 0;                                     ///< voxel edge, m
  long nx = 0, ny = 0;
  double columnX(long i) const { return origin_x + (i + 0.5) * h; }
  double columnY(long j) const { return origin_y + (j + 0.5) * h; }
  double layerZ(long k) const { return origin_z + k * h; }
};

/// The grid of voxel edge h over the bounding box [lo, hi] of a surface.
inline ColumnGrid columnGrid(const Vec3& lo, const Vec3& hi, double h) {
  ColumnGrid g;
  g.h = h;
  g.origin_x = lo.x() - kJitterX * h;
  g.origin_y = lo.y() - kJitterY * h;
  g.origin_z = lo.z() - kJitterZ * h;
  g.nx = long(std::ceil((hi.x() - g.origin_x) / h)) + 1;
  g.ny = long(std::ceil((hi.y() - g.origin_y) / h)) + 1;
  return g;
}

}  // namespace flsh::voxel
