#include "sim/soft/material_chain.h"

#include <Eigen/Geometry>

#include "flsh/energy/fem_material.h"
#include "flsh/volume/volumetric_data.h"
#include "sim/soft/node_masses.h"

namespace flsh::detail {

// The key names the mass cubature (node_masses.h): the ROM's inertial cubature or every tet.
const MaterialChain::Built& MaterialChain::built() const {
  if (built_) return *built_;
  const char* key =
      inertialMassCubature(avatar_) ? "material_chain.inertial" : "material_chain.lumped";
  built_ = avatar_.derived<Built>(key, [&] {
    const Cubature cubature = massCubature(avatar_);
    const VolumetricData& data = avatar_.volumetricData();
    const MaterialModel& model = data.material_model;
    auto out = std::make_unique<Built>();
    out->map = std::make_unique<TetMaterialMap>(tetMaterialGeometry(data),
                                                model.coefficientValues(avatar_.betas()));
    out->mass_coefficients = {model.coefficientIndex("density", MaterialModel::kSkin),
                              model.coefficientIndex("density", MaterialModel::kSoftTissue),
                              model.coefficientIndex("skin_thickness", MaterialModel::kBodyLevel)};
    // m_j = Σ_k w_k ρ_t vol_t / 4 over the mass cubature's tets t (node_masses.cpp).
    const MatX4i& tets = data.templ->mesh.tets;
    out->mass_derivatives = MatX3::Zero(data.numNodes(), 3);
    VecX bar = VecX::Zero(out->map->values().size());
    for (Eigen::Index k = 0; k < cubature.elements.size(); ++k) {
      const int t = cubature.elements[k];
      Mat34 X;
      for (int a = 0; a < 4; ++a) X.col(a) = data.rest_nodes.row(tets(t, a)).transpose();
      const double volume = tetSignedVolume(X);
      TetMaterialCotangent density;
      density.density = 1.0;
      bar.setZero();
      out->map->addCotangent(t, density, bar);
      Vec3 d;
      for (int i = 0; i < 3; ++i) d[i] = bar[out->mass_coefficients[size_t(i)]];
      const Vec3 quarter = (cubature.weights[k] * volume / 4) * d;
      for (int a = 0; a < 4; ++a) out->mass_derivatives.row(tets(t, a)) += quarter.transpose();
    }
    return out;
  });
  return *built_;
}

const TetMaterialMap& MaterialChain::map() const { return *built().map; }
const std::array<int, 3>& MaterialChain::massCoefficients() const {
  return built().mass_coefficients;
}
const MatX3& MaterialChain::massDerivatives() const { return built().mass_derivatives; }
int MaterialChain::numValues() const { return MaterialModel::numCoefficients(); }

VecX MaterialChain::parametersCotangent(const VecX& values_bar) const {
  return avatar_.volumetricData().material_model.parametersCotangent(values_bar, avatar_.betas());
}
VecX MaterialChain::valuesTangent(const VecX& parameters_direction) const {
  return avatar_.volumetricData().material_model.coefficientValuesTangent(parameters_direction,
                                                                          avatar_.betas());
}

}  // namespace flsh::detail
