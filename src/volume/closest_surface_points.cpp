// Closest points of a triangle surface (include/flsh/volume/closest_surface_points.h).
#include "flsh/volume/closest_surface_points.h"

#include <string>

#include "flsh/core/error.h"
#include "volume/surface_query.h"

namespace flsh {

ClosestSurfacePoints closestSurfacePoints(const MatX3& V, const MatX3i& F, const MatX3& points) {
  const std::string who = "closestSurfacePoints: ";
  if (F.rows() == 0) throw InputError(who + "faces has 0 rows, expected at least one triangle");
  if (!V.allFinite()) throw InputError(who + "vertices contain NaN or Inf");
  if (!points.allFinite()) throw InputError(who + "points contain NaN or Inf");
  if (F.minCoeff() < 0 || F.maxCoeff() >= V.rows())
    throw InputError(who + "faces index outside the " + std::to_string(V.rows()) +
                     " vertices (expected 0.." + std::to_string(V.rows() - 1) + ")");
  const detail::SurfaceDistance surface(V, F);
  ClosestSurfacePoints out;
  const Eigen::Index P = points.rows();
  out.faces.resize(P);
  out.barycentric.resize(P, 3);
  out.distances.resize(P);
#pragma omp parallel for schedule(dynamic, 256) if (P > 1000)
  for (Eigen::Index p = 0; p < P; ++p) {
    const detail::SurfaceDistance::Hit hit = surface.closest(points.row(p).transpose());
    out.faces[p] = hit.face;
    out.barycentric.row(p) = hit.barycentric.transpose();
    out.distances[p] = hit.distance;
  }
  return out;
}

}  // namespace flsh
