#include "sim/soft/elastic_elements.h"

#include <omp.h>

#include <algorithm>
#include <string>

#include "core/first_failure.h"
#include "flsh/core/error.h"
#include "flsh/volume/elastic_tets.h"
#include "flsh/volume/reduced_data.h"
#include "flsh/volume/tet_mesh.h"
#include "flsh/volume/volumetric_data.h"
#include "sim/soft/on_two_threads.h"

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
  out.tet = tets.tets;
  out.tets.resize(Eigen::Index(tets.size()), 4);
  for (int k = 0; k < tets.size(); ++k) out.tets.row(k) = all_tets.row(tets.tets[size_t(k)]);
  out.weights = Eigen::Map<const VecX>(kept_weight.data(), Eigen::Index(kept_weight.size()));
  out.rest = std::move(tets.rest);
  out.materials = std::move(tets.materials);
  return out;
}

double ReducedElasticity::evaluateElements(const SoftKinematics& kin, VecX* g, bool hessian,
                                           int offset, bool psd, int split_from) const {
  Mat3* values = hessian ? kin.reducedValues(1) : nullptr;
  const int T = numElements();
  const int base = offset + kin.boneDofs();
  double E = 0.0;
  const int threads = std::min(2, omp_get_max_threads());
  if (hessian || T < split_from || threads < 2 || omp_in_parallel()) {
    E = elements(0, T, g ? g->data() + base : nullptr, values, psd);
  } else {
    VecX second = g ? VecX::Zero(kin.numSoftDofs()) : VecX();
    double energies[2] = {0.0, 0.0};
    onTwoThreads([&](int part) {
      energies[part] = part == 0 ? elements(0, T / 2, g ? g->data() + base : nullptr, nullptr, psd)
                                 : elements(T / 2, T, g ? second.data() : nullptr, nullptr, psd);
    });
    E = energies[0] + energies[1];
    if (g) g->segment(base, second.size()) += second;
  }
  return E + restStiffness(g, values, offset);
}

VecX elementRestFloors(const ReducedData& rom, const ElasticElements& elements) {
  if (rom.elastic_floors.size() != rom.elastic.elements.size())
    throw InputError("Simulable: the avatar's reduced data has " +
                     std::to_string(rom.elastic_floors.size()) +
                     " rest-split floors, expected one per elastic cubature sample (" +
                     std::to_string(rom.elastic.elements.size()) + "; SoftAvatar fills them)");
  const int T = elements.size();
  VecX floors(T);
  Eigen::Index k = 0;
  for (int e = 0; e < T; ++e) {
    while (k < rom.elastic.elements.size() && rom.elastic.elements[k] != elements.tet[size_t(e)])
      ++k;
    if (k == rom.elastic.elements.size())
      throw InputError("Simulable: elastic element " + std::to_string(e) +
                       " is not a sample of the avatar's elastic cubature");
    floors[e] = rom.elastic_floors[k++];
  }
  return floors;
}

void ElasticityTerm::addHessianBlocks(const TermContext& c, std::vector<Triplet>& H,
                                      std::vector<FixedHessianBlocks>* blocks, int offset,
                                      bool psd) const {
  collectFixedBlocks(blocks,
                     [&](FixedHessianBlocks* fixed) { evaluate(nullptr, &H, offset, psd, fixed); });
}

namespace {

Mat3X gatherDirections(const std::vector<int>& dofs, const VecX& lambda, int offset) {
  Mat3X Lambda = Mat3X::Zero(3, Eigen::Index(dofs.size() / 3));
  for (size_t i = 0; i < dofs.size(); ++i)
    if (dofs[i] >= 0) Lambda(Eigen::Index(i % 3), Eigen::Index(i / 3)) = lambda[offset + dofs[i]];
  return Lambda;
}

}  // namespace

// λᵀ ∂g/∂c = Σ_e (chain of element e)ᵀ ∂(Λ_eᵀ g_e)/∂(material point): the element cotangents
// first (summed over a sweep's steps when accumulated), then one pass through the material map.
void ElasticityTerm::addParameterProducts(const TermContext&, const VecX& lambda,
                                          ParameterProducts<VecX>& out) const {
  if (!out.wants(SimParameter::Material)) return;
  MatX elements, rest_outer;
  accumulateMaterialProducts(lambda, elements, rest_outer);
  addAccumulatedMaterialProducts(elements, rest_outer, out[SimParameter::Material]);
}

// One pass for the material's and β's shares: each element's state (the ROMs' nodal form, the
// law at F) serves both.
void ElasticityTerm::accumulateMaterialProducts(const VecX& lambda, MatX& elements,
                                                MatX& rest_outer, const ShapeChain* shape,
                                                VecX* beta_bar) const {
  const int E = numProductElements();
  if (elements.size() == 0) elements = MatX::Zero(E, kMaterialPointValues);
  const bool with_shape = shape && beta_bar;
  // Each element costs microseconds (the law's dP/dF, the rest-shape kernels): threads pay from
  // a hundred elements on (the ROM's cubature samples). Per-thread β sums added in thread order.
  const int threads = E > 100 ? std::max(1, omp_get_max_threads()) : 1;
  std::vector<VecX> betas(size_t(threads), VecX::Zero(with_shape ? shape->numBetas() : 0));
  FirstFailure failure;
#pragma omp parallel num_threads(threads)
  {
    const int k = omp_get_thread_num();
    std::vector<int> dofs;
#pragma omp for schedule(static)
    for (int e = 0; e < E; ++e)
      failure.run([&] {
        materialElementDofs(e, dofs);
        FemMaterialDerivative d;
        Mat34 X_bar = Mat34::Zero();
        materialElementProducts(e, gatherDirections(dofs, lambda, 0), &d,
                                with_shape ? &X_bar : nullptr);
        elements.row(e).head<36>() += Eigen::Map<const Eigen::RowVectorXd>(d.C_world.data(), 36);
        elements(e, 36) += d.modulus;
        elements(e, 37) += d.gamma;
        if (with_shape)
          shape->addTetNodesCotangent(materialElementNodes(e), X_bar, betas[size_t(k)]);
      });
  }
  failure.rethrow();
  if (with_shape)
    for (const VecX& b : betas) *beta_bar += b;
  addRestOuter(lambda, rest_outer);
}

// On the available threads, per-thread sums added in thread order (deterministic for a fixed
// thread count).
void ElasticityTerm::addAccumulatedMaterialProducts(const MatX& elements, const MatX& rest_outer,
                                                    VecX& values_bar, const ShapeChain* shape,
                                                    VecX* beta_bar) const {
  const TetMaterialMap& map = chain_.map();
  const int E = int(elements.rows());
  const int threads = E > 1000 ? std::max(1, omp_get_max_threads()) : 1;
  std::vector<VecX> partial(size_t(threads), VecX::Zero(values_bar.size()));
  std::vector<VecX> betas(size_t(threads), VecX::Zero(shape ? shape->numBetas() : 0));
#pragma omp parallel num_threads(threads)
  {
    const int k = omp_get_thread_num();
#pragma omp for schedule(static)
    for (int e = 0; e < E; ++e) {
      TetMaterialCotangent bar;
      bar.C_world = Eigen::Map<const Mat6>(elements.row(e).head<36>().eval().data());
      bar.modulus = elements(e, 36);
      bar.gamma = elements(e, 37);
      const int t = materialElementTet(e);
      TetGeometryCotangent geometry;
      map.addCotangent(t, bar, partial[size_t(k)], shape ? &geometry : nullptr);
      if (shape) shape->addGeometryCotangent(t, geometry, betas[size_t(k)]);
    }
  }
  for (const VecX& p : partial) values_bar += p;
  if (beta_bar)
    for (const VecX& b : betas) *beta_bar += b;
  if (rest_outer.size() > 0) addRestStiffnessProducts(rest_outer, values_bar, shape, beta_bar);
}

void ElasticityTerm::addSoftStateOuter(const VecX& lambda, MatX& W) const {
  const int m = kin_.numSoftDofs();
  if (W.size() == 0) W = MatX::Zero(m, m);
  W.noalias() += lambda.segment(kin_.boneDofs(), m) * kin_.u.transpose();
}

void ElasticityTerm::addRestFormCotangents(const std::vector<int>& tet,
                                           const std::vector<TetElementRest>& rest,
                                           const std::vector<Mat6>& C_world,
                                           const MatX4i& mesh_tets,
                                           const std::function<bool(int, Mat9&)>& form,
                                           VecX& values_bar, const ShapeChain* shape,
                                           VecX* beta_bar) const {
  const TetMaterialMap& map = chain_.map();
  const int T = int(tet.size());
  const int threads = T > 1000 ? std::max(1, omp_get_max_threads()) : 1;
  std::vector<VecX> partial(size_t(threads), VecX::Zero(values_bar.size()));
  std::vector<VecX> betas(size_t(threads), VecX::Zero(shape ? shape->numBetas() : 0));
  const Eigen::Matrix<double, 6, 9>& S = voigtLinearStrainMatrix();
  FirstFailure failure;
#pragma omp parallel num_threads(threads)
  {
    const int k = omp_get_thread_num();
#pragma omp for schedule(static)
    for (int t = 0; t < T; ++t)
      failure.run([&] {
        Mat9 Tt;
        if (!form(t, Tt)) return;
        TetMaterialCotangent bar;
        bar.C_world = rest[size_t(t)].volume * S * Tt * S.transpose();
        TetGeometryCotangent geometry;
        map.addCotangent(tet[size_t(t)], bar, partial[size_t(k)], shape ? &geometry : nullptr);
        if (!shape) return;
        shape->addGeometryCotangent(tet[size_t(t)], geometry, betas[size_t(k)]);
        Mat34 X_bar = Mat34::Zero();
        addTetLinearFormRestCotangent(rest[size_t(t)], C_world[size_t(t)], Tt, 1.0, X_bar);
        shape->addTetNodesCotangent(mesh_tets.row(tet[size_t(t)]).transpose(), X_bar,
                                    betas[size_t(k)]);
      });
  }
  failure.rethrow();
  for (const VecX& p : partial) values_bar += p;
  if (beta_bar)
    for (const VecX& b : betas) *beta_bar += b;
}

template <class Visit>
void ElasticityTerm::forEachLocalUnit(int e, std::vector<int>& dofs, Visit&& visit) const {
  materialElementDofs(e, dofs);
  const Eigen::Index columns = Eigen::Index(dofs.size() / 3);
  for (size_t i = 0; i < dofs.size(); ++i) {
    if (dofs[i] < 0) continue;
    Mat3X unit = Mat3X::Zero(3, columns);
    unit(Eigen::Index(i % 3), Eigen::Index(i / 3)) = 1.0;
    visit(dofs[i], unit);
  }
}

template <class Row>
void ElasticityTerm::materialElementRows(int e, std::vector<int>& dofs, VecX& values,
                                         Row&& row) const {
  forEachLocalUnit(e, dofs, [&](int dof, const Mat3X& unit) {
    values.setZero(chain_.numValues());
    chain_.map().addCotangent(materialElementTet(e),
                              materialCotangent(materialElementGradient(e, unit)), values);
    row(dof, values);
  });
}

void ElasticityTerm::addParameterTangents(const TermContext&,
                                          const std::vector<ParameterDirection>& directions,
                                          std::vector<VecX>& out) const {
  const size_t m = size_t(SimParameter::Material);
  bool any = false;
  for (const ParameterDirection& d : directions) any = any || (d[m] && d[m]->size() > 0);
  if (!any) return;
  std::vector<int> dofs;
  VecX values;
  for (int e = 0; e < numMaterialElements(); ++e)
    materialElementRows(e, dofs, values, [&](int dof, const VecX& row) {
      for (size_t k = 0; k < directions.size(); ++k)
        if (directions[k][m] && directions[k][m]->size() > 0)
          out[k][dof] += row.dot(*directions[k][m]);
    });
}

void ElasticityTerm::addParameterJacobians(const TermContext&, ParameterProducts<MatX>& out) const {
  if (!out.wants(SimParameter::Material)) return;
  MatX& J = out[SimParameter::Material];
  std::vector<int> dofs;
  VecX values;
  for (int e = 0; e < numMaterialElements(); ++e)
    materialElementRows(e, dofs, values,
                        [&](int dof, const VecX& row) { J.row(dof) += row.transpose(); });
}

// ---- Shape ----------------------------------------------------------------------------------

void ElasticityTerm::addElementShapeCotangent(int e, const Mat3X& Lambda, const ShapeChain& shape,
                                              VecX& beta_bar, VecX& values_bar) const {
  FemMaterialDerivative d;
  Mat34 X_bar = Mat34::Zero();
  materialElementProducts(e, Lambda, &d, &X_bar);
  shape.addTetNodesCotangent(materialElementNodes(e), X_bar, beta_bar);
  const int t = materialElementTet(e);
  TetGeometryCotangent geometry;
  chain_.map().addCotangent(t, materialCotangent(d), values_bar, &geometry);
  shape.addGeometryCotangent(t, geometry, beta_bar);
}

// Element by element on the available threads (per-thread sums added in thread order), the
// coefficient values' share chained once.
void ElasticityTerm::addShapeProducts(const VecX& lambda, const ShapeChain& shape,
                                      VecX& beta_bar) const {
  const int E = numMaterialElements(), K = shape.numBetas();
  // Each element costs microseconds (the law's dP/dF and the rest-shape kernels): threads pay
  // from a hundred elements on (the ROM's cubature samples).
  const int threads = E > 100 ? std::max(1, omp_get_max_threads()) : 1;
  std::vector<VecX> betas(size_t(threads), VecX::Zero(K));
  // The coefficient values' cotangents: one per tet of the map.
  std::vector<VecX> values(size_t(threads), VecX::Zero(chain_.numValues()));
  FirstFailure failure;
#pragma omp parallel num_threads(threads)
  {
    const int k = omp_get_thread_num();
    std::vector<int> dofs;
#pragma omp for schedule(static)
    for (int e = 0; e < E; ++e)
      failure.run([&] {
        materialElementDofs(e, dofs);
        const Mat3X Lambda = gatherDirections(dofs, lambda, 0);
        if (Lambda.isZero(0.0)) return;
        addElementShapeCotangent(e, Lambda, shape, betas[size_t(k)], values[size_t(k)]);
      });
  }
  failure.rethrow();
  for (int k = 1; k < threads; ++k) {
    betas[0] += betas[size_t(k)];
    values[0] += values[size_t(k)];
  }
  beta_bar += betas[0];
  beta_bar.noalias() += shape.valuesJacobian().transpose() * values[0];
}

template <class Row>
void ElasticityTerm::shapeRows(const ShapeChain& shape, Row&& row) const {
  std::vector<int> dofs;
  VecX beta(shape.numBetas()), values(chain_.numValues());
  for (int e = 0; e < numMaterialElements(); ++e)
    forEachLocalUnit(e, dofs, [&](int dof, const Mat3X& unit) {
      beta.setZero();
      values.setZero();
      addElementShapeCotangent(e, unit, shape, beta, values);
      beta.noalias() += shape.valuesJacobian().transpose() * values;
      row(dof, beta);
    });
}

void ElasticityTerm::addShapeTangent(const VecX& dbeta, const ShapeChain& shape, VecX& out) const {
  shapeRows(shape, [&](int dof, const VecX& r) { out[dof] += r.dot(dbeta); });
}

void ElasticityTerm::addShapeJacobian(const ShapeChain& shape, MatX& J) const {
  shapeRows(shape, [&](int dof, const VecX& r) { J.row(dof) += r.transpose(); });
}

}  // namespace flsh::detail
