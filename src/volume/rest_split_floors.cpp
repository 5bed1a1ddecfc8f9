// The floors of the ROM's rest-stiffness split, per elastic cubature sample (reduced_data.h).
#include <algorithm>
#include <string>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/energy/fem_material.h"
#include "flsh/volume/elastic_tets.h"
#include "flsh/volume/reduced_data.h"
#include "volume/subspace_tets.h"

namespace flsh {

// Each kept sample tet's rest Hessian K̃_e in its handles' coordinates (handles of its nodes'
// basis rows, ascending; F = I + Z G̃ᵀ, G̃ = G Φ_e), assembled without and with the weights,
// then restSplitFloors (fem_material.h) against K.
VecX elasticCubatureFloors(const VolumetricData& data, const ReducedData& rom) {
  const std::string fn = "elasticCubatureFloors: ";
  const Cubature& cubature = rom.elastic;
  VecX floors = VecX::Constant(cubature.elements.size(), kUnusedRestSplitFloor);
  if (cubature.elements.size() == 0 || rom.elastic_rest_stiffness.size() == 0) return floors;
  const int T = data.numTets(), m = rom.numSoftDofs();
  if (rom.elastic_rest_stiffness.rows() != m || rom.elastic_rest_stiffness.cols() != m)
    throw InputError(fn + "elastic_rest_stiffness is not (3·#handles + #modes) square");
  std::vector<int> kept, position;
  for (Eigen::Index k = 0; k < cubature.elements.size(); ++k) {
    const int t = cubature.elements[k];
    if (t < 0 || t >= T)
      throw InputError(fn + "the elastic cubature names tet " + std::to_string(t) +
                       ", expected [0, " + std::to_string(T) + ")");
    if (!tetHasSoftNode(data, t)) continue;  // no energy: the simulable drops it
    kept.push_back(t);
    position.push_back(int(k));
  }
  const ElasticTets tets = elasticTets(data, kept, "elasticCubatureFloors");
  const SpMat rows = rom.basis.transpose();  // φ by rows
  const MatX4i& mesh_tets = data.templ->mesh.tets;
  MatX unit = MatX::Zero(m, m), weighted = MatX::Zero(m, m);
  VecX weights(Eigen::Index(kept.size()));
  for (size_t e = 0; e < kept.size(); ++e) {
    weights[Eigen::Index(e)] = cubature.weights[position[e]];
    if (rom.numModes() > 0) {  // K̃_e = V Dᵀ A₀ D on the tet's soft-state entries
      const detail::SubspaceTet st = detail::subspaceTet(data, rom, rows, tets.rest[e], kept[e]);
      const MatX K =
          tets.rest[e].volume * st.D.transpose() * (detail::restTangent(tets.materials[e]) * st.D);
      for (size_t a = 0; a < st.dofs.size(); ++a)
        for (size_t b = 0; b < st.dofs.size(); ++b) {
          unit(st.dofs[a], st.dofs[b]) += K(Eigen::Index(a), Eigen::Index(b));
          weighted(st.dofs[a], st.dofs[b]) +=
              weights[Eigen::Index(e)] * K(Eigen::Index(a), Eigen::Index(b));
        }
      continue;
    }
    std::vector<int> handles;
    for (int a = 0; a < 4; ++a) {
      const int j = mesh_tets(kept[e], a);
      if (data.bone_of_node[j] >= 0) continue;
      for (SpMat::InnerIterator it(rows, j); it; ++it) handles.push_back(int(it.row()));
    }
    std::sort(handles.begin(), handles.end());
    handles.erase(std::unique(handles.begin(), handles.end()), handles.end());
    const int count = int(handles.size());
    if (count == 0) continue;
    Mat4X Phi = Mat4X::Zero(4, count);
    for (int a = 0; a < 4; ++a) {
      const int j = mesh_tets(kept[e], a);
      if (data.bone_of_node[j] >= 0) continue;
      for (SpMat::InnerIterator it(rows, j); it; ++it)
        Phi(a, std::lower_bound(handles.begin(), handles.end(), int(it.row())) - handles.begin()) =
            it.value();
    }
    MatX K = MatX::Zero(3 * count, 3 * count);
    Eigen::Ref<MatX> view = K;
    reducedTetElasticEnergy(tets.rest[e].volume, tets.materials[e],
                            reducedShapeGradients(tets.rest[e], Phi), Mat3X::Zero(3, count),
                            nullptr, &view, false);
    for (int s = 0; s < count; ++s)
      for (int r = 0; r < count; ++r) {
        const int a = handles[size_t(s)], b = handles[size_t(r)];
        unit.block<3, 3>(3 * a, 3 * b) += K.block<3, 3>(3 * s, 3 * r);
        weighted.block<3, 3>(3 * a, 3 * b) +=
            weights[Eigen::Index(e)] * K.block<3, 3>(3 * s, 3 * r);
      }
  }
  try {
    const VecX kept_floors = restSplitFloors(rom.elastic_rest_stiffness, unit, weighted, weights);
    for (size_t e = 0; e < kept.size(); ++e) floors[position[e]] = kept_floors[Eigen::Index(e)];
  } catch (const InputError& error) {
    throw InputError(std::string("the avatar's elastic cubature (ReducedData): ") + error.what());
  }
  return floors;
}

}  // namespace flsh
