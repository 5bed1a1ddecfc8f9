#include "flsh/volume/elastic_tets.h"

#include <string>

#include "core/first_failure.h"
#include "flsh/core/error.h"
#include "flsh/volume/material_point.h"
#include "flsh/volume/tet_mesh.h"

namespace flsh {

bool tetHasSoftNode(const VolumetricData& data, int t) {
  const MatX4i& tets = data.templ->mesh.tets;
  for (int a = 0; a < 4; ++a)
    if (data.bone_of_node[tets(t, a)] < 0) return true;
  return false;
}

ElasticTets elasticTets(const VolumetricData& data, std::vector<int> tets, const char* origin) {
  const MatX4i& all = data.templ->mesh.tets;
  for (int t : tets)
    if (t < 0 || t >= all.rows())
      throw InputError(std::string(origin) + ": tet " + std::to_string(t) + ", expected [0, " +
                       std::to_string(all.rows()) + ")");
  ElasticTets out;
  out.tets = std::move(tets);
  const int E = out.size();
  out.rest.resize(size_t(E));
  out.materials.resize(size_t(E));
  detail::FirstFailure failure;
#pragma omp parallel for schedule(dynamic, 64)
  for (int k = 0; k < E; ++k)
    failure.run([&] {
      const int t = out.tets[size_t(k)];
      Mat34 X;
      for (int a = 0; a < 4; ++a) X.col(a) = data.rest_nodes.row(all(t, a)).transpose();
      out.rest[size_t(k)] = tetElementRest(X, t);
      out.materials[size_t(k)] = femMaterialPoint(data.materials, t);
    });
  failure.rethrow();
  return out;
}

ElasticTets deformableTets(const VolumetricData& data) {
  std::vector<int> tets;
  for (int t = 0; t < int(data.templ->mesh.tets.rows()); ++t)
    if (tetHasSoftNode(data, t)) tets.push_back(t);
  return elasticTets(data, std::move(tets));
}

}  // namespace flsh
