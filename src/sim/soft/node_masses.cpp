#include "sim/soft/node_masses.h"

#include <Eigen/Geometry>
#include <cmath>

#include "flsh/volume/reduced_data.h"
#include "flsh/volume/volumetric_data.h"

namespace flsh::detail {

NodeMasses nodeMasses(const SoftAvatar& avatar) {
  const VolumetricData& data = avatar.volumetricData();
  const MatX4i& tets = data.templ->mesh.tets;
  const MatX3& rest = data.rest_nodes;
  NodeMasses out;
  const ReducedData* rom = avatar.reducedModelEnabled() ? &avatar.reducedData() : nullptr;
  if (rom && rom->inertial.elements.size() > 0) {
    out.mass = inertialNodeMasses(data, rom->inertial);
  } else {
    out.mass = VecX::Zero(data.numNodes());
    for (Eigen::Index e = 0; e < tets.rows(); ++e) {
      Vec3 X[4];
      for (int a = 0; a < 4; ++a) X[a] = rest.row(tets(e, a)).transpose();
      const double volume = std::abs((X[1] - X[0]).cross(X[2] - X[0]).dot(X[3] - X[0])) / 6.0;
      const double node_mass = data.materials.density[e] * volume / 4.0;
      for (int a = 0; a < 4; ++a) out.mass[tets(e, a)] += node_mass;
    }
  }
  for (Eigen::Index j = 0; j < out.mass.size(); ++j)
    if (out.mass[j] > 0.0) out.nodes.push_back(int(j));
  return out;
}

}  // namespace flsh::detail
