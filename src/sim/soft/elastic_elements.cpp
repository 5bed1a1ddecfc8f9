#include "sim/soft/elastic_elements.h"

#include <string>

#include "flsh/core/error.h"
#include "flsh/volume/material_point.h"
#include "flsh/volume/reduced_data.h"
#include "flsh/volume/volumetric_data.h"

namespace flsh::detail {

ElasticElements elasticElements(const SoftAvatar& avatar, const SoftKinematics& kinematics) {
  const VolumetricData& data = avatar.volumetricData();
  const MatX4i& all_tets = data.templ->mesh.tets;
  const ReducedData* rom = avatar.reducedModelEnabled() ? &avatar.reducedData() : nullptr;
  auto hasSoftNode = [&](int e) {
    for (int a = 0; a < 4; ++a)
      if (kinematics.isSoftNode(all_tets(e, a))) return true;
    return false;
  };
  std::vector<int> kept;
  std::vector<double> kept_weight;
  if (rom && rom->elastic.elements.size() > 0) {
    for (Eigen::Index k = 0; k < rom->elastic.elements.size(); ++k) {
      const int e = rom->elastic.elements[k];
      if (e < 0 || e >= all_tets.rows())
        throw InputError("Simulable: the avatar's elastic cubature names tet " + std::to_string(e) +
                         ", expected [0, " + std::to_string(all_tets.rows()) + ")");
      if (!hasSoftNode(e)) continue;  // zero energy whatever the state
      kept.push_back(e);
      kept_weight.push_back(rom->elastic.weights[k]);
    }
  } else {
    for (int e = 0; e < all_tets.rows(); ++e)
      if (hasSoftNode(e)) {
        kept.push_back(e);
        kept_weight.push_back(1.0);
      }
  }
  ElasticElements out;
  out.tets.resize(Eigen::Index(kept.size()), 4);
  out.weights = Eigen::Map<const VecX>(kept_weight.data(), Eigen::Index(kept_weight.size()));
  out.rest.reserve(kept.size());
  out.materials.reserve(kept.size());
  const MatX3& rest = kinematics.restNodes();
  for (size_t k = 0; k < kept.size(); ++k) {
    const int e = kept[k];
    out.tets.row(Eigen::Index(k)) = all_tets.row(e);
    Mat34 X;
    for (int a = 0; a < 4; ++a) X.col(a) = rest.row(all_tets(e, a)).transpose();
    out.rest.push_back(tetElementRest(X, e));
    out.materials.push_back(femMaterialPoint(data.materials, e));
  }
  return out;
}

void ElasticityTerm::addHessianBlocks(const TermContext& c, std::vector<Triplet>& H,
                                      std::vector<FixedHessianBlocks>* blocks, int offset,
                                      bool psd) const {
  collectFixedBlocks(blocks,
                     [&](FixedHessianBlocks* fixed) { evaluate(nullptr, &H, offset, psd, fixed); });
}

}  // namespace flsh::detail
