#include "sim/soft/shape_chain.h"

#include <Eigen/Geometry>

#include "flsh/energy/fem_material.h"
#include "flsh/volume/tet_material_map.h"
#include "flsh/volume/volumetric_data.h"
#include "sim/soft/node_masses.h"

namespace flsh::detail {

Eigen::Block<const MatX, 3, Eigen::Dynamic> ShapeChain::nodeDirections(int j) const {
  return avatar_.volumetricData().templ->fields.shapedirs.middleRows<3>(3 * Eigen::Index(j));
}

void ShapeChain::addNodeCotangent(const MatX3& X_bar, VecX& beta_bar) const {
  const MatX& S = avatar_.volumetricData().templ->fields.shapedirs;
  // S is 3#N × K with row 3j + c. Row by row: the node terms' cotangents are nonzero on their
  // few nodes only (the mass nodes and the contact candidates).
  for (Eigen::Index j = 0; j < X_bar.rows(); ++j)
    if (!X_bar.row(j).isZero(0.0))
      beta_bar.noalias() += S.middleRows<3>(3 * j).transpose() * X_bar.row(j).transpose();
}

void ShapeChain::addTetNodesCotangent(const Eigen::Vector4i& nodes, const Mat34& X_bar,
                                      VecX& beta_bar) const {
  for (int a = 0; a < 4; ++a)
    beta_bar.noalias() += nodeDirections(nodes[a]).transpose() * X_bar.col(a);
}

void ShapeChain::addGeometryCotangent(int t, const TetGeometryCotangent& geometry,
                                      VecX& beta_bar) const {
  if (geometry.area == 0.0 && geometry.volume == 0.0) return;
  beta_bar.noalias() += geometry.area * areaJacobian().row(t).transpose() +
                        geometry.volume * volumeJacobian().row(t).transpose();
}

MatX3 ShapeChain::nodeTangent(const VecX& dbeta) const {
  const VecX d = avatar_.volumetricData().templ->fields.shapedirs * dbeta;
  return Eigen::Map<const MatX3>(d.data(), d.size() / 3, 3);
}

const MatX& ShapeChain::valuesJacobian() const { return built().values; }
const MatX& ShapeChain::areaJacobian() const { return built().area; }
const MatX& ShapeChain::volumeJacobian() const { return built().volume; }
const MatX& ShapeChain::massJacobian() const { return built().mass; }

// Forward mode over the K columns: dX̄ = S e_k moves each tet's area and volume; with dc the
// column of ∂c/∂β, m_j = Σ_k w_k ρ_t vol_t / 4 (signed volume, as node_masses) moves by
// w_k (dρ_t vol_t + ρ_t dvol_t) / 4. The key names the mass cubature (as MaterialChain's).
const ShapeChain::Built& ShapeChain::built() const {
  if (built_) return *built_;
  // The material map first: it is derived data of the avatar too, and derived() holds the
  // avatar's lock while it builds.
  const TetMaterialMap& map = materials_.map();
  const char* key = inertialMassCubature(avatar_) ? "shape_chain.inertial" : "shape_chain.lumped";
  built_ = avatar_.derived<Built>(key, [&] {
    const VolumetricData& data = avatar_.volumetricData();
    const TetMesh& mesh = data.templ->mesh;
    const int K = numBetas();
    auto out = std::make_unique<Built>();
    out->values = data.material_model.coefficientValuesShapeJacobian(avatar_.betas());
    tetMaterialGeometryTangent(mesh, data.rest_nodes, data.templ->fields.shapedirs, out->area,
                               out->volume);
    const Cubature cubature = massCubature(avatar_);
    out->mass = MatX::Zero(data.numNodes(), K);
    for (Eigen::Index i = 0; i < cubature.elements.size(); ++i) {
      const int t = cubature.elements[i];
      Mat34 X;
      for (int a = 0; a < 4; ++a) X.col(a) = data.rest_nodes.row(mesh.tets(t, a)).transpose();
      const double volume = tetSignedVolume(X);
      const double sign = volume < 0 ? -1.0 : 1.0;
      Eigen::RowVectorXd dm(K);
      for (int k = 0; k < K; ++k) {
        const double d_rho =
            map.densityTangent(t, out->values.col(k), out->area(t, k), out->volume(t, k));
        dm[k] = d_rho * volume + data.materials.density[t] * sign * out->volume(t, k);
      }
      dm *= cubature.weights[i] / 4;
      for (int a = 0; a < 4; ++a) out->mass.row(mesh.tets(t, a)) += dm;
    }
    return out;
  });
  return *built_;
}

}  // namespace flsh::detail
