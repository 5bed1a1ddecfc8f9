#include "sim/soft/node_masses.h"

#include "flsh/volume/reduced_data.h"
#include "flsh/volume/volumetric_data.h"

namespace flsh::detail {

NodeMasses nodeMasses(const SoftAvatar& avatar) {
  const VolumetricData& data = avatar.volumetricData();
  const ReducedData* rom = avatar.reducedModelEnabled() ? &avatar.reducedData() : nullptr;
  NodeMasses out;
  if (rom && rom->inertial.elements.size() > 0) {
    out.mass = inertialNodeMasses(data, rom->inertial);
  } else {  // lumped masses: every tet, weight 1
    const int T = data.numTets();
    Cubature every;
    every.elements = VecXi::LinSpaced(T, 0, T - 1);
    every.weights = VecX::Ones(T);
    out.mass = inertialNodeMasses(data, every);
  }
  for (Eigen::Index j = 0; j < out.mass.size(); ++j)
    if (out.mass[j] > 0.0) out.nodes.push_back(int(j));
  return out;
}

}  // namespace flsh::detail
