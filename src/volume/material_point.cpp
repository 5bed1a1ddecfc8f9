#include "flsh/volume/material_point.h"

#include <string>

#include "flsh/core/error.h"

namespace flsh {

FemMaterialPoint femMaterialPoint(const TetMaterials& materials, int t) {
  const std::string where = "femMaterialPoint: tet " + std::to_string(t);
  const auto check = [&](long size, const char* field) {
    if (t < 0 || t >= size)
      throw InputError(where + ": TetMaterials." + field + " has " + std::to_string(size) +
                       " rows, expected more than " + std::to_string(t));
  };
  check(materials.young.rows(), "young");
  check(materials.poisson.rows(), "poisson");
  check(materials.shear.rows(), "shear");
  check(materials.fung.size(), "fung");
  check(static_cast<long>(materials.frame.size()), "frame");
  try {
    return makeFemMaterialPoint(
        materials.young.row(t).transpose(), materials.poisson.row(t).transpose(),
        materials.shear.row(t).transpose(), materials.frame[t], materials.fung[t]);
  } catch (const InputError& e) {
    throw InputError(where + ": " + e.what());
  }
}

}  // namespace flsh
