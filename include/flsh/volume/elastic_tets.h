// The tets of an avatar's tet mesh whose elastic energy can change, with what the material law
// needs of each at rest: shared by the soft skeletons' elastic terms (sim/) and the ROM's
// precomputation (reduced_data.h), which sum the same energy.
#pragma once

#include <vector>

#include "flsh/energy/fem_material.h"
#include "flsh/volume/volumetric_data.h"

namespace flsh {

/// Whether tet t has a soft-tissue node: a tet of bone nodes only moves rigidly with its bones
/// and has zero elastic energy whatever the state.
bool tetHasSoftNode(const VolumetricData& data, int t);

/// Template tets with their rest shape gradients (at data.rest_nodes) and material points
/// (femMaterialPoint), index k for tets[k].
struct ElasticTets {
  std::vector<int> tets;
  std::vector<TetElementRest> rest;
  std::vector<FemMaterialPoint> materials;
  int size() const { return int(tets.size()); }
};

/// `tets` with their rest data, computed on the available threads. InputError for a tet index
/// outside the mesh (naming it and `origin`) or as tetElementRest / femMaterialPoint.
ElasticTets elasticTets(const VolumetricData& data, std::vector<int> tets,
                        const char* origin = "elasticTets");
/// Every tet with a soft-tissue node, ascending.
ElasticTets deformableTets(const VolumetricData& data);

}  // namespace flsh
