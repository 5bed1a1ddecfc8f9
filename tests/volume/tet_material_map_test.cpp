// The per-tet material map (volume/tet_material_map.h): it reproduces the avatar's materials,
// its reverse-mode derivative against central differences for tets of every kind (inside, on
// the surface with a skin mixture, all skin), and SoftAvatar::withMaterial keeps the
// discretization while re-evaluating the materials; the chain between the coefficient values
// and the material file's parameters at a non-zero β.
#include "flsh/volume/tet_material_map.h"

#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <string>

#include "flsh/core/error.h"
#include "flsh/volume/material_point.h"
#include "flsh/volume/soft_avatar.h"
#include "support/small_soft_avatar.h"
#include "support/test_support.h"

namespace flsh {
namespace {

using test::jacobianMatchesFiniteDifferences;
using test::randomVector;
using test::SoftModel;

const VolumetricData& data() { return test::smallSoftAvatar(SoftModel::Fem)->volumetricData(); }

double relativeDifference(const MatX& a, const MatX& b) {
  return (a - b).cwiseAbs().maxCoeff() / std::max(1e-300, b.cwiseAbs().maxCoeff());
}

TEST(TetMaterialMap, ReproducesTheAvatarsMaterials) {
  const VolumetricData& d = data();
  const TetMaterialMap map(tetMaterialGeometry(d), d.material_model.coefficientValues(VecX()));
  const TetMaterials m = map.materials();
  EXPECT_LT(relativeDifference(m.density, d.materials.density), 1e-12);
  EXPECT_LT(relativeDifference(m.young, d.materials.young), 1e-12);
  EXPECT_LT(relativeDifference(m.poisson, d.materials.poisson), 1e-12);
  EXPECT_LT(relativeDifference(m.shear, d.materials.shear), 1e-12);
  EXPECT_LT(relativeDifference(m.fung, d.materials.fung), 1e-12);
  EXPECT_LT(relativeDifference(m.skin_fraction, d.materials.skin_fraction), 1e-12);
  EXPECT_EQ(m.layer, d.materials.layer);
}

/// One tet of each kind: inside (f = 0), a skin mixture (0 < f < 1), all skin (f = 1) if any.
std::vector<int> tetsOfEveryKind(const TetMaterialMap& map) {
  int inside = -1, mixed = -1, skin = -1;
  for (int t = 0; t < map.numTets(); ++t) {
    const double f = map.skinFraction(t);
    if (f == 0 && inside < 0) inside = t;
    if (f > 0.2 && f < 0.8 && mixed < 0) mixed = t;
    if (f == 1 && skin < 0) skin = t;
  }
  std::vector<int> out;
  for (int t : {inside, mixed, skin})
    if (t >= 0) out.push_back(t);
  return out;
}

// s(c) = ⟨C̄, C_world⟩ + μ̄ μ + γ̄ γ + ρ̄ ρ of one tet, differentiated in x with c = c₀ ⊙ exp(x)
// (relative steps for coefficients of every magnitude): ∂s/∂x = c₀ ⊙ addCotangent.
TEST(TetMaterialMap, CotangentMatchesFiniteDifferences) {
  const VolumetricData& d = data();
  const TetMaterialGeometry geometry = tetMaterialGeometry(d);
  const VecX c0 = d.material_model.coefficientValues(VecX());
  const TetMaterialMap map(geometry, c0);
  const std::vector<int> tets = tetsOfEveryKind(map);
  ASSERT_GE(tets.size(), 2u) << "an inside tet and a skin mixture";
  TetMaterialCotangent bar;
  bar.C_world = Eigen::Map<const Mat6>(randomVector(36, 1.0, 3).data());
  bar.modulus = 0.7;
  bar.gamma = -2e4;
  bar.density = 30.0;
  for (int t : tets) {
    SCOPED_TRACE("tet " + std::to_string(t) + ", skin fraction " +
                 std::to_string(map.skinFraction(t)));
    VecX values_bar = VecX::Zero(c0.size());
    map.addCotangent(t, bar, values_bar);
    const auto s = [&](const VecX& x) {
      const TetMaterials m =
          TetMaterialMap(geometry, c0.cwiseProduct(x.array().exp().matrix())).materials();
      const FemMaterialPoint p = femMaterialPoint(m, t);
      return VecX::Constant(1, bar.C_world.cwiseProduct(p.C_world).sum() + bar.modulus * p.modulus +
                                   bar.gamma * p.gamma + bar.density * m.density[t]);
    };
    EXPECT_TRUE(jacobianMatchesFiniteDifferences(
        s, VecX::Zero(c0.size()), MatX(values_bar.cwiseProduct(c0).transpose()), 1e-7, 1e-6));
  }
}

// The geometry's tangent in the rest nodes, and the map's cotangent of the tets' area and volume
// (through the skin fraction) and its density tangent, against central differences.
TEST(TetMaterialMap, GeometryDerivativesMatchFiniteDifferences) {
  const VolumetricData& d = data();
  const TetMesh& mesh = d.templ->mesh;
  const VecX direction = randomVector(3 * d.numNodes(), 1e-3, 5);
  const MatX3 dX = Eigen::Map<const MatX3>(direction.data(), d.numNodes(), 3);
  MatX area_tangent, volume_tangent;
  tetMaterialGeometryTangent(mesh, d.rest_nodes, MatX(direction), area_tangent, volume_tangent);
  const VecX d_area = area_tangent.col(0), d_volume = volume_tangent.col(0);
  ASSERT_GT(d_area.norm(), 0.0);
  ASSERT_GT(d_volume.norm(), 0.0);
  const auto geometry_at = [&](double s) {
    return tetMaterialGeometry(mesh, d.rest_nodes + s * dX, d.templ->fields.weights,
                               d.materials.frame);
  };
  const double h = 1e-4;
  const TetMaterialGeometry plus = geometry_at(h), minus = geometry_at(-h);
  EXPECT_LT(relativeDifference((plus.boundary_area - minus.boundary_area) / (2 * h), d_area), 1e-6);
  EXPECT_LT(relativeDifference((plus.volume - minus.volume) / (2 * h), d_volume), 1e-6);

  // The material point and density of a skin-mixture tet as functions of (area, volume, c).
  const VecX c0 = d.material_model.coefficientValues(VecX());
  const TetMaterialGeometry g0 = tetMaterialGeometry(d);
  const TetMaterialMap map(g0, c0);
  const std::vector<int> tets = tetsOfEveryKind(map);
  int mixed = -1;
  for (int t : tets)
    if (map.skinFraction(t) > 0 && map.skinFraction(t) < 1) mixed = t;
  ASSERT_GE(mixed, 0);
  TetMaterialCotangent bar;
  bar.C_world = Eigen::Map<const Mat6>(randomVector(36, 1.0, 3).data());
  bar.modulus = 0.7;
  bar.gamma = -2e4;
  bar.density = 30.0;
  VecX values_bar = VecX::Zero(c0.size());
  TetGeometryCotangent geometry_bar;
  map.addCotangent(mixed, bar, values_bar, &geometry_bar);
  ASSERT_NE(geometry_bar.area, 0.0);
  ASSERT_NE(geometry_bar.volume, 0.0);
  const double A = g0.boundary_area[mixed], V = g0.volume[mixed];
  const auto s = [&](const VecX& x) {  // relative steps of the area and the volume
    TetMaterialGeometry g = g0;
    g.boundary_area[mixed] = A * (1 + x[0]);
    g.volume[mixed] = V * (1 + x[1]);
    const TetMaterials m = TetMaterialMap(g, c0).materials();
    const FemMaterialPoint p = femMaterialPoint(m, mixed);
    return VecX::Constant(1, bar.C_world.cwiseProduct(p.C_world).sum() + bar.modulus * p.modulus +
                                 bar.gamma * p.gamma + bar.density * m.density[mixed]);
  };
  MatX analytic(1, 2);
  analytic << geometry_bar.area * A, geometry_bar.volume * V;
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(s, VecX::Zero(2), analytic, 1e-7, 1e-6));
  // The density's tangent in (c, area, volume) is the density part of the same derivative.
  const VecX dc = c0.cwiseProduct(randomVector(c0.size(), 0.1, 8));
  const double dA = 0.1 * A, dV = -0.05 * V;
  const auto density = [&](double t) {
    TetMaterialGeometry g = g0;
    g.boundary_area[mixed] = A + t * dA;
    g.volume[mixed] = V + t * dV;
    return TetMaterialMap(g, c0 + t * dc).materials().density[mixed];
  };
  const double fd = (density(1e-5) - density(-1e-5)) / 2e-5;
  const double analytic_density = map.densityTangent(mixed, dc, dA, dV);
  ASSERT_NE(analytic_density, 0.0);
  EXPECT_NEAR(analytic_density, fd, 1e-6 * std::abs(fd));
}

TEST(TetMaterialMap, RejectsValuesOfTheWrongSize) {
  const std::string message = test::messageOf<InputError>(
      [] { TetMaterialMap(tetMaterialGeometry(data()), VecX::Ones(3)); });
  EXPECT_NE(message.find("values"), std::string::npos) << message;
}

// withMaterial: the same discretization, the materials of the new model (and for the ROM the
// subspace's rest stiffness at them), the floors kept; the same model gives the same data.
TEST(TetMaterialMap, WithMaterialKeepsTheDiscretization) {
  for (SoftModel model : {SoftModel::Fem, SoftModel::Rom}) {
    const auto avatar = test::smallSoftAvatar(model);
    const VolumetricData& d = avatar->volumetricData();
    MaterialModel stiffer = d.material_model;
    const VecX slopes = stiffer.logSlopes("E1", MaterialModel::kSoftTissue);
    stiffer.setCoefficient("E1", MaterialModel::kSoftTissue,
                           2.0 * stiffer.baseValue("E1", MaterialModel::kSoftTissue), slopes);
    stiffer.setCoefficient("density", MaterialModel::kSkin,
                           1.1 * stiffer.baseValue("density", MaterialModel::kSkin),
                           stiffer.logSlopes("density", MaterialModel::kSkin));
    const auto other = avatar->withMaterial(stiffer);
    const VolumetricData& o = other->volumetricData();
    EXPECT_EQ(o.rest_nodes, d.rest_nodes);
    EXPECT_EQ(o.bone_of_node, d.bone_of_node);
    EXPECT_EQ(o.templ, d.templ);
    EXPECT_TRUE(o.material_model == stiffer);
    EXPECT_NE(o.key, d.key);
    const TetMaterials expected =
        TetMaterialMap(tetMaterialGeometry(d), stiffer.coefficientValues(VecX())).materials();
    EXPECT_LT(relativeDifference(o.materials.young, expected.young), 1e-12);
    EXPECT_LT(relativeDifference(o.materials.density, expected.density), 1e-12);
    EXPECT_GT(relativeDifference(o.materials.young, d.materials.young), 0.1);
    const auto same = avatar->withMaterial(d.material_model);
    EXPECT_LT(relativeDifference(same->volumetricData().materials.young, d.materials.young), 1e-12);
    if (model == SoftModel::Rom) {
      const ReducedData& r = avatar->reducedData();
      const ReducedData& ro = other->reducedData();
      EXPECT_EQ(ro.handles, r.handles);
      EXPECT_EQ(ro.elastic.elements, r.elastic.elements);
      EXPECT_EQ(ro.elastic.weights, r.elastic.weights);
      ASSERT_EQ(ro.elastic_floors.size(), r.elastic.elements.size());
      EXPECT_EQ(ro.elastic_floors, r.elastic_floors);
      EXPECT_LT(relativeDifference(ro.elastic_rest_stiffness, elasticRestStiffness(o, r.basis)),
                1e-12);
      EXPECT_GT(relativeDifference(ro.elastic_rest_stiffness, r.elastic_rest_stiffness), 0.01);
      EXPECT_LT(
          relativeDifference(same->reducedData().elastic_rest_stiffness, r.elastic_rest_stiffness),
          1e-12);
      // The floors are those the avatar computed from its own materials.
      EXPECT_EQ(r.elastic_floors, elasticCubatureFloors(d, r));
    }
  }
}

TEST(TetMaterialMap, WithMaterialRefusesAModelForAnotherBody) {
  const auto avatar = test::smallSoftAvatar(SoftModel::Fem);
  const int K = int(avatar->betas().size());
  const std::string message =
      test::messageOf<InputError>([&] { avatar->withMaterial(MaterialModel::defaults(K + 1)); });
  EXPECT_NE(message.find("shape components"), std::string::npos) << message;
}

// withShape: the same tet mesh, bone nodes and frames; the rest data of a new avatar at β′; the
// rest nodes X̄(β′) and the materials of the model at β′ on the geometry there; the ROM's data
// kept but K.
TEST(TetMaterialMap, WithShapeKeepsTheDiscretization) {
  for (SoftModel model : {SoftModel::Fem, SoftModel::Rom}) {
    const auto avatar = test::smallSoftAvatar(model);
    const VolumetricData& d = avatar->volumetricData();
    const int K = int(avatar->betas().size());
    VecX beta = VecX::Zero(K);
    beta.head(2) << 0.8, -0.5;
    const auto other = avatar->withShape(beta);
    const VolumetricData& o = other->volumetricData();
    EXPECT_EQ(other->betas(), beta);
    EXPECT_EQ(o.templ, d.templ);
    EXPECT_EQ(o.bone_of_node, d.bone_of_node);
    EXPECT_NE(o.key, d.key);
    EXPECT_LT(relativeDifference(o.rest_nodes, shapedNodes(d.templ->mesh, d.templ->fields, beta)),
              1e-14);
    EXPECT_GT(relativeDifference(o.rest_nodes, d.rest_nodes), 1e-3);
    for (size_t t = 0; t < d.materials.frame.size(); ++t)
      ASSERT_EQ(o.materials.frame[t], d.materials.frame[t]);
    const TetMaterials expected =
        TetMaterialMap(tetMaterialGeometry(d.templ->mesh, o.rest_nodes, d.templ->fields.weights,
                                           d.materials.frame),
                       d.material_model.coefficientValues(beta))
            .materials();
    EXPECT_LT(relativeDifference(o.materials.young, expected.young), 1e-12);
    EXPECT_LT(relativeDifference(o.materials.density, expected.density), 1e-12);
    // The skeleton's rest data are a new avatar's.
    SoftAvatar fresh(avatar->bodyPtr(), beta, avatar->settings());
    fresh.initVolumetricData();
    EXPECT_LT(relativeDifference(other->restVertices(), fresh.restVertices()), 1e-14);
    EXPECT_LT(relativeDifference(other->restJoints(), fresh.restJoints()), 1e-14);
    EXPECT_LT(relativeDifference(other->vertexAreas(), fresh.vertexAreas()), 1e-14);
    EXPECT_EQ(o.rest_joints, other->restJoints());
    if (model == SoftModel::Rom) {
      const ReducedData& r = avatar->reducedData();
      const ReducedData& ro = other->reducedData();
      EXPECT_EQ(ro.handles, r.handles);
      EXPECT_EQ(ro.elastic.elements, r.elastic.elements);
      EXPECT_EQ(ro.elastic_floors, r.elastic_floors);
      EXPECT_LT(relativeDifference(ro.elastic_rest_stiffness, elasticRestStiffness(o, r.basis)),
                1e-12);
    }
    const auto same = avatar->withShape(avatar->betas());
    EXPECT_LT(relativeDifference(same->volumetricData().materials.young, d.materials.young), 1e-12);
    EXPECT_THROW(avatar->withShape(VecX::Ones(K + 1)), InputError);
  }
}

// The coefficient values c_i(β) = exp(a_i + b_iᵀβ) and their chain to (a, b), at a non-zero β.
TEST(MaterialModelChain, ValuesCotangentAndTangentMatchFiniteDifferences) {
  const int K = 4;
  const MaterialModel model = MaterialModel::defaults(K);
  const VecX beta = randomVector(K, 1.0, 21);
  const VecX p0 = model.parameters();
  const VecX values_bar = randomVector(MaterialModel::numCoefficients(), 1.0, 22);
  const auto f = [&](const VecX& p) {
    MaterialModel m = model;
    m.setParameters(p);
    return VecX::Constant(
        1, values_bar.dot(m.coefficientValues(beta).cwiseQuotient(model.coefficientValues(beta))));
  };
  // Relative values (divided by c(β)), so that every coefficient's scale is 1.
  const VecX c = model.coefficientValues(beta);
  const VecX g = model.parametersCotangent(values_bar.cwiseQuotient(c), beta);
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(f, p0, MatX(g.transpose()), 1e-7, 1e-6));
  const VecX dp = randomVector(model.numParameters(), 1.0, 23);
  const VecX dc = model.coefficientValuesTangent(dp, beta);
  EXPECT_NEAR(dc.cwiseQuotient(c).dot(values_bar), g.dot(dp), 1e-12 * std::abs(g.dot(dp)));
  // ∂c/∂β, relative.
  const MatX dc_dbeta = model.coefficientValuesShapeJacobian(beta);
  ASSERT_GT(dc_dbeta.norm(), 0.0);
  EXPECT_TRUE(jacobianMatchesFiniteDifferences(
      [&](const VecX& b) { return VecX(model.coefficientValues(b).cwiseQuotient(c)); }, beta,
      MatX(c.cwiseInverse().asDiagonal() * dc_dbeta), 1e-7, 1e-6));
  EXPECT_EQ(int(model.parameterNames().size()), model.numParameters());
  EXPECT_EQ(model.parameterNames()[size_t(model.parameterOffset("E1", MaterialModel::kSkin))],
            "layers.skin.E1.log_value");
}

}  // namespace
}  // namespace flsh
