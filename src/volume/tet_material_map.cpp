// The per-tet material map and its reverse-mode derivative (tet_material_map.h).
#include "flsh/volume/tet_material_map.h"

#include <Eigen/Geometry>
#include <Eigen/LU>
#include <cmath>
#include <string>

#include "flsh/core/error.h"
#include "flsh/energy/fem_material.h"
#include "flsh/volume/volumetric_data.h"
#include "volume/surface_query.h"

namespace flsh {

namespace {

/// Indices into MaterialModel::coefficientValues, looked up once.
struct CoefficientIndices {
  // Per layer: density, E1..3, ν12, ν13, ν23, G12, G13, G23, fung_gamma (layerQuantities order).
  int layer[MaterialModel::kNumLayers][11];
  int skin_thickness;
  std::vector<int> stiffness_scale;  // per region
};

const CoefficientIndices& indices() {
  static const CoefficientIndices table = [] {
    const MaterialModel m = MaterialModel::defaults(0);
    CoefficientIndices c{};
    const std::vector<std::string>& q = MaterialModel::layerQuantities();
    for (int l = 0; l < MaterialModel::kNumLayers; ++l)
      for (int k = 0; k < 11; ++k) c.layer[l][k] = m.coefficientIndex(q[size_t(k)], l);
    c.skin_thickness = m.coefficientIndex("skin_thickness", MaterialModel::kBodyLevel);
    for (int r = 0; r < MaterialModel::numRegions(); ++r)
      c.stiffness_scale.push_back(
          m.coefficientIndex("stiffness_scale", MaterialModel::regionLevel(r)));
    return c;
  }();
  return table;
}
enum LayerEntry { kDensity, kE1, kE2, kE3, kNu12, kNu13, kNu23, kG12, kG13, kG23, kFung };

}  // namespace

TetMaterialGeometry tetMaterialGeometry(const TetMesh& mesh, const MatX3& shaped_nodes,
                                        const MatX& node_weights, std::vector<Mat3> frames) {
  const std::string fn = "tetMaterialGeometry: ";
  detail::checkTetMesh(mesh, shaped_nodes, "tetMaterialGeometry", false);
  const int nt = mesh.numTets();
  if (node_weights.rows() != mesh.numNodes())
    throw InputError(fn + "node_weights has " + std::to_string(node_weights.rows()) +
                     " rows, expected " + std::to_string(mesh.numNodes()) + " (one per node)");
  if (int(frames.size()) != nt)
    throw InputError(fn + "frames has " + std::to_string(frames.size()) + " entries, expected " +
                     std::to_string(nt) + " (one per tet)");
  TetMaterialGeometry g;
  g.boundary_area = VecX::Zero(nt);
  g.volume.resize(nt);
  for (int t = 0; t < nt; ++t) {
    const Vec3 x0 = shaped_nodes.row(mesh.tets(t, 0));
    g.volume[t] = std::abs((shaped_nodes.row(mesh.tets(t, 1)).transpose() - x0)
                               .cross(shaped_nodes.row(mesh.tets(t, 2)).transpose() - x0)
                               .dot(shaped_nodes.row(mesh.tets(t, 3)).transpose() - x0) /
                           6);
  }
  std::vector<int> owners;
  const MatX3i F = detail::outwardBoundaryFaces(mesh, "tetMaterialGeometry", &owners);
  for (int f = 0; f < F.rows(); ++f) {
    const Vec3 a = shaped_nodes.row(F(f, 0)), b = shaped_nodes.row(F(f, 1)),
               c = shaped_nodes.row(F(f, 2));
    g.boundary_area[owners[size_t(f)]] += 0.5 * (b - a).cross(c - a).norm();
  }
  const MatX omega = MaterialModel::regionWeights(node_weights);
  g.region_weights = MatX::Zero(nt, omega.cols());
  for (int t = 0; t < nt; ++t)
    for (int k = 0; k < 4; ++k) g.region_weights.row(t) += 0.25 * omega.row(mesh.tets(t, k));
  g.frame = std::move(frames);
  return g;
}

TetMaterialGeometry tetMaterialGeometry(const VolumetricData& data) {
  if (!data.templ) throw InputError("tetMaterialGeometry: the volumetric data has no template");
  return tetMaterialGeometry(data.templ->mesh, data.rest_nodes, data.templ->fields.weights,
                             data.materials.frame);
}

TetMaterialMap::TetMaterialMap(TetMaterialGeometry geometry, const VecX& values)
    : geometry_(std::move(geometry)), values_(values) {
  const int n = MaterialModel::numCoefficients();
  if (values.size() != n || !values.allFinite() || (values.array() <= 0).any())
    throw InputError("TetMaterialMap: values has " + std::to_string(values.size()) +
                     " entries, expected " + std::to_string(n) + " finite values > 0 " +
                     "(MaterialModel::coefficientValues)");
  const CoefficientIndices& ix = indices();
  for (int l = 0; l < MaterialModel::kNumLayers; ++l) {
    auto v = [&](int entry) { return values[ix.layer[l][entry]]; };
    layers_[l] = Layer{v(kDensity),
                       v(kFung),
                       Vec3(v(kE1), v(kE2), v(kE3)),
                       Vec3(v(kNu12), v(kNu13), v(kNu23)),
                       Vec3(v(kG12), v(kG13), v(kG23)),
                       Mat3::Zero()};
    layers_[l].normal_stiffness = normalCompliance(layers_[l].young, layers_[l].poisson).inverse();
  }
  skin_thickness_ = values[ix.skin_thickness];
  log_stiffness_scale_.resize(MaterialModel::numRegions());
  for (int r = 0; r < MaterialModel::numRegions(); ++r)
    log_stiffness_scale_[r] = std::log(values[ix.stiffness_scale[size_t(r)]]);
  if (geometry_.region_weights.rows() != geometry_.size() ||
      geometry_.region_weights.cols() != MaterialModel::numRegions() ||
      geometry_.boundary_area.size() != geometry_.size() ||
      int(geometry_.frame.size()) != geometry_.size())
    throw InputError("TetMaterialMap: the geometry's arrays do not have one row per tet");
}

// Skin under a boundary face (area × thickness, to first order in thickness) goes to the tet
// owning the face, capped at the tet's volume (computeTetMaterials).
double TetMaterialMap::skinFraction(int t) const {
  const double area = geometry_.boundary_area[t];
  if (area == 0) return 0;
  const double skin = area * skin_thickness_;
  return skin >= geometry_.volume[t] ? 1.0 : skin / geometry_.volume[t];
}

double TetMaterialMap::stiffnessScale(int t) const {
  return std::exp(geometry_.region_weights.row(t).dot(log_stiffness_scale_));
}

TetMaterials TetMaterialMap::materials() const {
  const int nt = numTets();
  TetMaterials out;
  out.density.resize(nt);
  out.young.resize(nt, 3);
  out.poisson.resize(nt, 3);
  out.shear.resize(nt, 3);
  out.fung.resize(nt);
  out.frame = geometry_.frame;
  out.layer.resize(nt);
  out.skin_fraction.resize(nt);
  out.tissue_stiffness_scale.resize(nt);
  const Layer& skin = layers_[MaterialModel::kSkin];
  for (int t = 0; t < nt; ++t) {
    // The soft-tissue layer of this tet's body region: moduli scaled, ν unchanged (a positive
    // multiple of a positive-definite stiffness).
    Layer tissue = layers_[MaterialModel::kSoftTissue];
    const double k = stiffnessScale(t);
    out.tissue_stiffness_scale[t] = k;
    tissue.young *= k;
    tissue.shear *= k;
    tissue.normal_stiffness *= k;
    const double f = skinFraction(t);
    out.skin_fraction[t] = f;
    out.layer[t] = f >= 0.5 ? MaterialModel::kSkin : MaterialModel::kSoftTissue;
    if (f == 0 || f == 1) {
      const Layer& l = f == 1 ? skin : tissue;
      out.density[t] = l.density;
      out.fung[t] = l.fung;
      out.young.row(t) = l.young.transpose();
      out.poisson.row(t) = l.poisson.transpose();
      out.shear.row(t) = l.shear.transpose();
      continue;
    }
    // Voigt mixture: volume average of the stiffness tensors (same frame, so still orthotropic
    // and positive definite), converted back to engineering constants.
    out.density[t] = f * skin.density + (1 - f) * tissue.density;
    out.fung[t] = f * skin.fung + (1 - f) * tissue.fung;
    out.shear.row(t) = (f * skin.shear + (1 - f) * tissue.shear).transpose();
    const Mat3 compliance =
        (f * skin.normal_stiffness + (1 - f) * tissue.normal_stiffness).inverse();
    const Vec3 young(1 / compliance(0, 0), 1 / compliance(1, 1), 1 / compliance(2, 2));
    out.young.row(t) = young.transpose();
    out.poisson.row(t) << -compliance(0, 1) * young[0], -compliance(0, 2) * young[0],
        -compliance(1, 2) * young[1];
  }
  return out;
}

// Each tet's (and boundary face's) gradient in its nodes, once, applied to the D directions.
void tetMaterialGeometryTangent(const TetMesh& mesh, const MatX3& shaped_nodes,
                                const MatX& directions, MatX& d_area, MatX& d_volume) {
  detail::checkTetMesh(mesh, shaped_nodes, "tetMaterialGeometryTangent", false);
  if (directions.rows() != 3 * shaped_nodes.rows())
    throw InputError("tetMaterialGeometryTangent: directions has " +
                     std::to_string(directions.rows()) +
                     " rows, expected 3 · #nodes = " + std::to_string(3 * shaped_nodes.rows()));
  const int nt = mesh.numTets();
  const Eigen::Index D = directions.cols();
  d_area = MatX::Zero(nt, D);
  d_volume = MatX::Zero(nt, D);
  auto x = [&](int j) -> Vec3 { return shaped_nodes.row(j).transpose(); };
  auto add = [&](MatX& out, int row, int j, const Vec3& gradient) {
    out.row(row).noalias() += gradient.transpose() * directions.middleRows<3>(3 * Eigen::Index(j));
  };
  for (int t = 0; t < nt; ++t) {
    // vol = det[x1 − x0, x2 − x0, x3 − x0]/6, ∂det/∂x_k = cofactor column k − 1; |vol|' =
    // sign(vol) vol'.
    Mat3 Dm;
    for (int k = 0; k < 3; ++k) Dm.col(k) = x(mesh.tets(t, k + 1)) - x(mesh.tets(t, 0));
    const double sign = (Dm.determinant() < 0 ? -1.0 : 1.0) / 6;
    Mat3 cof;
    cof << Dm.col(1).cross(Dm.col(2)), Dm.col(2).cross(Dm.col(0)), Dm.col(0).cross(Dm.col(1));
    for (int k = 0; k < 3; ++k) add(d_volume, t, mesh.tets(t, k + 1), sign * cof.col(k));
    add(d_volume, t, mesh.tets(t, 0), -sign * cof.rowwise().sum());
  }
  std::vector<int> owners;
  const MatX3i F = detail::outwardBoundaryFaces(mesh, "tetMaterialGeometryTangent", &owners);
  for (int f = 0; f < F.rows(); ++f) {
    // A = ½ |n|, n = (b − a) × (c − a): ∂A/∂b = ½ (c − a) × n̂, ∂A/∂c = ½ n̂ × (b − a),
    // ∂A/∂a = −(the two).
    const Vec3 a = x(F(f, 0)), b = x(F(f, 1)), c = x(F(f, 2));
    const Vec3 n = (b - a).cross(c - a);
    const double length = n.norm();
    if (length == 0) continue;
    const Vec3 unit = n / length;
    const Vec3 gb = 0.5 * (c - a).cross(unit), gc = 0.5 * unit.cross(b - a);
    const int t = owners[size_t(f)];
    add(d_area, t, F(f, 0), -(gb + gc));
    add(d_area, t, F(f, 1), gb);
    add(d_area, t, F(f, 2), gc);
  }
}

double TetMaterialMap::densityTangent(int t, const VecX& values_direction, double d_area,
                                      double d_volume) const {
  const CoefficientIndices& ix = indices();
  const double f = skinFraction(t);
  const double rho_skin = layers_[MaterialModel::kSkin].density;
  const double rho_tissue = layers_[MaterialModel::kSoftTissue].density;
  const double d_skin = values_direction[ix.layer[MaterialModel::kSkin][kDensity]];
  const double d_tissue = values_direction[ix.layer[MaterialModel::kSoftTissue][kDensity]];
  double df = 0.0;
  if (f > 0 && f < 1)  // f = A t / |vol|
    df = f *
         (d_area / geometry_.boundary_area[t] +
          values_direction[ix.skin_thickness] / skin_thickness_ - d_volume / geometry_.volume[t]);
  return f * d_skin + (1 - f) * d_tissue + df * (rho_skin - rho_tissue);
}

void TetMaterialMap::addCotangent(int t, const TetMaterialCotangent& bar, VecX& values_bar,
                                  TetGeometryCotangent* geometry_bar) const {
  if (t < 0 || t >= numTets())
    throw InputError("TetMaterialMap::addCotangent: tet " + std::to_string(t) + " of " +
                     std::to_string(numTets()));
  if (values_bar.size() != values_.size())
    throw InputError("TetMaterialMap::addCotangent: values_bar has " +
                     std::to_string(values_bar.size()) + " entries, expected " +
                     std::to_string(values_.size()));
  const CoefficientIndices& ix = indices();
  const Layer& skin = layers_[MaterialModel::kSkin];
  const Layer& tissue = layers_[MaterialModel::kSoftTissue];
  const double f = skinFraction(t), s = stiffnessScale(t);

  // C_world = Tᵀ C T: C̄ = T C̄_world Tᵀ; C = [N, diag(G23, G13, G12)].
  const Mat6 T = frameStrainMap(geometry_.frame[size_t(t)]);
  const Mat6 C_bar = T * bar.C_world * T.transpose();
  Mat3 N_bar = C_bar.topLeftCorner<3, 3>();
  const Vec3 G_bar(C_bar(5, 5), C_bar(4, 4), C_bar(3, 3));  // G12, G13, G23
  // μ = mean of E_i = 1 / (N⁻¹)_ii: dE_i = E_i² (N⁻¹ dN N⁻¹)_ii.
  const Mat3 N = f * skin.normal_stiffness + (1 - f) * s * tissue.normal_stiffness;
  const Mat3 S = N.inverse();
  for (int i = 0; i < 3; ++i) {
    const double E = 1 / S(i, i);
    N_bar += (bar.modulus / 3 * E * E) * S.col(i) * S.row(i);
  }
  // The mixture.
  const double gamma_bar = bar.gamma, rho_bar = bar.density;
  const Mat3 N_skin_bar = f * N_bar, N_tissue_bar = (1 - f) * s * N_bar;
  const Vec3 G_skin_bar = f * G_bar, G_tissue_bar = (1 - f) * s * G_bar;
  const double s_bar =
      (1 - f) * ((N_bar.cwiseProduct(tissue.normal_stiffness)).sum() + G_bar.dot(tissue.shear));
  const double f_bar =
      (N_bar.cwiseProduct(skin.normal_stiffness - s * tissue.normal_stiffness)).sum() +
      G_bar.dot(skin.shear - s * tissue.shear) + gamma_bar * (skin.fung - tissue.fung) +
      rho_bar * (skin.density - tissue.density);
  // Each layer: N = S(E, ν)⁻¹, dN = −N dS N.
  auto layer = [&](int l, const Layer& L, const Mat3& Nb, const Vec3& Gb, double fung_bar,
                   double density_bar) {
    auto at = [&](int entry) -> double& { return values_bar[ix.layer[l][entry]]; };
    const Mat3 Sb = -L.normal_stiffness * Nb * L.normal_stiffness;
    const Vec3& E = L.young;
    const Vec3& nu = L.poisson;
    const double s01 = Sb(0, 1) + Sb(1, 0), s02 = Sb(0, 2) + Sb(2, 0), s12 = Sb(1, 2) + Sb(2, 1);
    at(kE1) += (-Sb(0, 0) + s01 * nu[0] + s02 * nu[1]) / (E[0] * E[0]);
    at(kE2) += (-Sb(1, 1) + s12 * nu[2]) / (E[1] * E[1]);
    at(kE3) += -Sb(2, 2) / (E[2] * E[2]);
    at(kNu12) += -s01 / E[0];
    at(kNu13) += -s02 / E[0];
    at(kNu23) += -s12 / E[1];
    at(kG12) += Gb[0];
    at(kG13) += Gb[1];
    at(kG23) += Gb[2];
    at(kFung) += fung_bar;
    at(kDensity) += density_bar;
  };
  layer(MaterialModel::kSkin, skin, N_skin_bar, G_skin_bar, f * gamma_bar, f * rho_bar);
  layer(MaterialModel::kSoftTissue, tissue, N_tissue_bar, G_tissue_bar, (1 - f) * gamma_bar,
        (1 - f) * rho_bar);
  // s = exp(Σ_r ω_r log c_r): ∂s/∂c_r = s ω_r / c_r.
  for (int r = 0; r < MaterialModel::numRegions(); ++r) {
    const double w = geometry_.region_weights(t, r);
    if (w == 0) continue;
    const int i = ix.stiffness_scale[size_t(r)];
    values_bar[i] += s_bar * s * w / values_[i];
  }
  // f = A t / |vol| below the cap, constant (0 or 1) elsewhere.
  if (f > 0 && f < 1) {
    values_bar[ix.skin_thickness] += f_bar * geometry_.boundary_area[t] / geometry_.volume[t];
    if (geometry_bar) {
      geometry_bar->area += f_bar * f / geometry_.boundary_area[t];
      geometry_bar->volume -= f_bar * f / geometry_.volume[t];
    }
  }
}

}  // namespace flsh
