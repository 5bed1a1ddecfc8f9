#include "sim/soft/node_masses.h"

#include "flsh/volume/reduced_data.h"
#include "flsh/volume/volumetric_data.h"

namespace flsh::detail {

bool inertialMassCubature(const SoftAvatar& avatar) {
  return avatar.reducedModelEnabled() && avatar.reducedData().inertial.elements.size() > 0;
}

Cubature massCubature(const SoftAvatar& avatar) {
  if (inertialMassCubature(avatar)) return avatar.reducedData().inertial;
  return exactCubature(avatar.volumetricData().numTets());  // lumped masses: every tet
}

NodeMasses nodeMasses(const SoftAvatar& avatar) {
  NodeMasses out;
  out.mass = inertialNodeMasses(avatar.volumetricData(), massCubature(avatar));
  for (Eigen::Index j = 0; j < out.mass.size(); ++j)
    if (out.mass[j] > 0.0) out.nodes.push_back(int(j));
  return out;
}

}  // namespace flsh::detail
