#include "sim/soft/material_chain.h"

#include <Eigen/Geometry>

#include "flsh/energy/fem_material.h"
#include "flsh/volume/volumetric_data.h"
#include "sim/soft/node_masses.h"

namespace flsh::detail {

void MaterialChain::build() const {
  if (map_) return;
  const VolumetricData& data = avatar_.volumetricData();
  const MaterialModel& model = data.material_model;
  auto map = std::make_unique<TetMaterialMap>(tetMaterialGeometry(data),
                                              model.coefficientValues(avatar_.betas()));
  mass_coefficients_ = {model.coefficientIndex("density", MaterialModel::kSkin),
                        model.coefficientIndex("density", MaterialModel::kSoftTissue),
                        model.coefficientIndex("skin_thickness", MaterialModel::kBodyLevel)};
  // m_j = Σ_k w_k ρ_t vol_t / 4 over the mass cubature's tets t (node_masses.cpp).
  const Cubature cubature = massCubature(avatar_);
  const MatX4i& tets = data.templ->mesh.tets;
  mass_derivatives_ = MatX3::Zero(data.numNodes(), 3);
  VecX bar = VecX::Zero(map->values().size());
  for (Eigen::Index k = 0; k < cubature.elements.size(); ++k) {
    const int t = cubature.elements[k];
    Mat34 X;
    for (int a = 0; a < 4; ++a) X.col(a) = data.rest_nodes.row(tets(t, a)).transpose();
    const double volume = tetSignedVolume(X);
    TetMaterialCotangent density;
    density.density = 1.0;
    bar.setZero();
    map->addCotangent(t, density, bar);
    Vec3 d;
    for (int i = 0; i < 3; ++i) d[i] = bar[mass_coefficients_[size_t(i)]];
    const Vec3 quarter = (cubature.weights[k] * volume / 4) * d;
    for (int a = 0; a < 4; ++a) mass_derivatives_.row(tets(t, a)) += quarter.transpose();
  }
  map_ = std::move(map);
}

const TetMaterialMap& MaterialChain::map() const {
  build();
  return *map_;
}
const std::array<int, 3>& MaterialChain::massCoefficients() const {
  build();
  return mass_coefficients_;
}
const MatX3& MaterialChain::massDerivatives() const {
  build();
  return mass_derivatives_;
}
int MaterialChain::numValues() const { return MaterialModel::numCoefficients(); }

VecX MaterialChain::parametersCotangent(const VecX& values_bar) const {
  return avatar_.volumetricData().material_model.parametersCotangent(values_bar, avatar_.betas());
}
VecX MaterialChain::valuesTangent(const VecX& parameters_direction) const {
  return avatar_.volumetricData().material_model.coefficientValuesTangent(parameters_direction,
                                                                          avatar_.betas());
}

}  // namespace flsh::detail
