#include "sim/soft/elastic_elements.h"

#include <string>

#include "flsh/core/error.h"
#include "flsh/volume/elastic_tets.h"
#include "flsh/volume/reduced_data.h"
#include "flsh/volume/tet_mesh.h"
#include "flsh/volume/volumetric_data.h"

namespace flsh::detail {

ElasticElements elasticElements(const SoftAvatar& avatar) {
  const VolumetricData& data = avatar.volumetricData();
  const ReducedData* rom = avatar.reducedModelEnabled() ? &avatar.reducedData() : nullptr;
  std::vector<int> kept;
  std::vector<double> kept_weight;
  if (rom && rom->elastic.elements.size() > 0) {
    const int num_tets = data.numTets();
    for (Eigen::Index k = 0; k < rom->elastic.elements.size(); ++k) {
      const int e = rom->elastic.elements[k];
      if (e < 0 || e >= num_tets)
        throw InputError("Simulable: the avatar's elastic cubature names tet " + std::to_string(e) +
                         ", expected [0, " + std::to_string(num_tets) + ")");
      if (!tetHasSoftNode(data, e)) continue;  // zero energy whatever the state
      kept.push_back(e);
      kept_weight.push_back(rom->elastic.weights[k]);
    }
  } else {
    for (int e = 0; e < data.numTets(); ++e)
      if (tetHasSoftNode(data, e)) {
        kept.push_back(e);
        kept_weight.push_back(1.0);
      }
  }
  ElasticTets tets = elasticTets(data, std::move(kept), "Simulable");
  const MatX4i& all_tets = data.templ->mesh.tets;
  ElasticElements out;
  out.tets.resize(Eigen::Index(tets.size()), 4);
  for (int k = 0; k < tets.size(); ++k) out.tets.row(k) = all_tets.row(tets.tets[size_t(k)]);
  out.weights = Eigen::Map<const VecX>(kept_weight.data(), Eigen::Index(kept_weight.size()));
  out.rest = std::move(tets.rest);
  out.materials = std::move(tets.materials);
  return out;
}

void ElasticityTerm::addHessianBlocks(const TermContext& c, std::vector<Triplet>& H,
                                      std::vector<FixedHessianBlocks>* blocks, int offset,
                                      bool psd) const {
  collectFixedBlocks(blocks,
                     [&](FixedHessianBlocks* fixed) { evaluate(nullptr, &H, offset, psd, fixed); });
}

}  // namespace flsh::detail
