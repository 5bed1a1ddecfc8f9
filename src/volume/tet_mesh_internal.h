// Helpers shared by the tet-mesh sources (src/volume/tet_mesh*.cpp); not part of the API.
#pragma once

#include <algorithm>
#include <array>
#include <vector>

#include "flsh/core/types.h"

namespace flsh {

/// Tets in the canonical order of tetrahedralizeSurface, independent of how they were produced:
/// each rotated by an even permutation to start at its smallest index (orientation kept), rows
/// sorted. Returns #T × 4.
inline MatX4i canonicalTets(std::vector<std::array<int, 4>> tets) {
  for (auto& tet : tets) {
    const int smallest = int(std::min_element(tet.begin(), tet.end()) - tet.begin());
    if (smallest != 0) {
      std::swap(tet[0], tet[size_t(smallest)]);
      // A second transposition of the two other entries keeps the orientation.
      const int other_a = smallest == 1 ? 2 : 1, other_b = smallest == 3 ? 2 : 3;
      std::swap(tet[size_t(other_a)], tet[size_t(other_b)]);
    }
  }
  std::sort(tets.begin(), tets.end());
  MatX4i out(Eigen::Index(tets.size()), 4);
  for (size_t r = 0; r < tets.size(); ++r)
    for (int k = 0; k < 4; ++k) out(Eigen::Index(r), k) = tets[r][size_t(k)];
  return out;
}

}  // namespace flsh
