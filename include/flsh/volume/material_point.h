// A tet's material point for the elastic law (flsh/energy/fem_material.h) from an avatar's
// per-tet coefficients (TetMaterials, flsh/volume/materials.h).
#pragma once

#include "flsh/energy/fem_material.h"
#include "flsh/volume/materials.h"

namespace flsh {

/// Material point of tet t of `materials` (rows young/poisson/shear/fung/frame at t).
/// InputError if t is out of range of any of these arrays, or as makeFemMaterialPoint (the
/// message names the tet).
FemMaterialPoint femMaterialPoint(const TetMaterials& materials, int t);

}  // namespace flsh
