// The nodes that carry mass in a soft skeleton and their masses: every tet node with its lumped
// mass (FEM; ROM without an inertial cubature), or the inertial cubature's few nodes (ROM).
// Read by nodal inertia and gravity alike.
#pragma once

#include <vector>

#include "flsh/core/types.h"
#include "flsh/volume/cubature.h"
#include "flsh/volume/soft_avatar.h"

namespace flsh::detail {

struct NodeMasses {
  std::vector<int> nodes;  ///< the nodes with mass > 0, ascending
  VecX mass;               ///< #N, kg (0 off `nodes`)
};

/// The tets and weights the node masses sum: the ROM's inertial cubature when its avatar has
/// one, else every tet with weight 1.
Cubature massCubature(const SoftAvatar& avatar);
/// Whether massCubature(avatar) is the ROM's inertial cubature (else every tet).
bool inertialMassCubature(const SoftAvatar& avatar);

/// Lumped masses m_j = Σ_{e ∋ j} ρ_e vol_e / 4 at the rest nodes X̄(β), or the inertial
/// cubature's when the avatar's ROM has one.
NodeMasses nodeMasses(const SoftAvatar& avatar);

}  // namespace flsh::detail
