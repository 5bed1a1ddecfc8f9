#include "sim/soft/reduced_elasticity_term.h"

#include <algorithm>
#include <string>

#include "flsh/core/error.h"
#include "flsh/volume/elastic_tets.h"
#include "flsh/volume/reduced_data.h"
#include "flsh/volume/volumetric_data.h"
#include "sim/soft/nodal_element_derivatives.h"

namespace flsh::detail {

ReducedElasticityTerm::ReducedElasticityTerm(const SoftAvatar& avatar,
                                             const SoftKinematics& kinematics,
                                             const MaterialChain& chain, ElasticElements elements)
    : ElasticityTerm(kinematics, chain), avatar_(avatar), elements_(std::move(elements)) {
  const ReducedData& rom = avatar.reducedData();
  const int H = kin_.numHandles();
  if (rom.elastic_rest_stiffness.size() > 0) {
    rest_stiffness_ = rom.elastic_rest_stiffness;
    if (rest_stiffness_.rows() != 3 * H || rest_stiffness_.cols() != 3 * H)
      throw InputError("Simulable: the avatar's elastic rest stiffness is " +
                       std::to_string(rest_stiffness_.rows()) + " × " +
                       std::to_string(rest_stiffness_.cols()) + ", expected 3·#handles square (" +
                       std::to_string(3 * H) + ")");
    for (int a = 0; a < H; ++a)
      for (int b = 0; b < H; ++b)
        if (!rest_stiffness_.block<3, 3>(3 * a, 3 * b).isZero(0.0))
          rest_stiffness_blocks_.emplace_back(a, b);
  }
  // Each element's handles and its shape gradients through the basis.
  ReducedTets samples = reducedTets(elements_.tet, elements_.tets, elements_.rest);
  handle_start_ = std::move(samples.handle_start);
  handles_ = std::move(samples.handles);
  gradients_ = std::move(samples.gradients);
  max_handles_ = samples.max_handles;
  const int T = elements_.size();
  if (rest_stiffness_.size() > 0) {  // each sample tet's own rest quadratic K̃_e
    rest_hessian_start_.assign(1, 0);
    for (int e = 0; e < T; ++e) {
      const int m = 3 * (handle_start_[size_t(e) + 1] - handle_start_[size_t(e)]);
      rest_hessian_start_.push_back(rest_hessian_start_.back() + m * m);
    }
    rest_hessians_.resize(rest_hessian_start_.back());
    for (int e = 0; e < T; ++e) {
      const int begin = handle_start_[size_t(e)], count = handle_start_[size_t(e) + 1] - begin;
      const int m = 3 * count;
      if (count == 0) continue;
      Eigen::Map<MatX> K(rest_hessians_.data() + rest_hessian_start_[size_t(e)], m, m);
      Eigen::Ref<MatX> view = K;
      reducedTetElasticEnergy(elements_.rest[size_t(e)].volume, elements_.materials[size_t(e)],
                              gradients_.middleCols(begin, count), Mat3X::Zero(3, count), nullptr,
                              &view, false);
    }
    rest_floors_ = elementRestFloors(rom, elements_);
  }
}

Mat3X ReducedElasticityTerm::handleDisplacements(const int* handles, int n) const {
  Mat3X Z(3, n);
  for (int s = 0; s < n; ++s) Z.col(s) = kin_.u.segment<3>(3 * handles[s]);
  return Z;
}

// Φ(a, s) = φ_{handles[s]}(nodes[a]) from the nodes' basis rows.
Mat4X ReducedElasticityTerm::nodeBasis(const Eigen::Vector4i& nodes, const int* handles,
                                       int n) const {
  Mat4X Phi = Mat4X::Zero(4, n);
  for (int a = 0; a < 4; ++a)
    for (auto* phi = kin_.basisBegin(nodes[a]); phi != kin_.basisEnd(nodes[a]); ++phi)
      for (int s = 0; s < n; ++s)
        if (handles[s] == phi->first) Phi(a, s) = phi->second;
  return Phi;
}

ReducedElasticityTerm::ReducedTets ReducedElasticityTerm::reducedTets(
    const std::vector<int>& tet, const MatX4i& tets,
    const std::vector<TetElementRest>& rest) const {
  const int E = int(tets.rows());
  // Per tet (in parallel): the handles whose φ reaches one of its nodes, and their gradients.
  std::vector<std::vector<int>> handles(static_cast<size_t>(E));
  std::vector<Mat3X> gradients(static_cast<size_t>(E));
#pragma omp parallel for schedule(dynamic, 256) if (E > 1000)
  for (int e = 0; e < E; ++e) {
    std::vector<int>& h = handles[size_t(e)];
    kin_.tetHandles(tets.row(e).transpose(), h);
    const Mat4X Phi = nodeBasis(tets.row(e).transpose(), h.data(), int(h.size()));
    gradients[size_t(e)] = reducedShapeGradients(rest[size_t(e)], Phi);
  }
  ReducedTets out;
  out.tet = tet;
  out.handle_start.assign(1, 0);
  out.volume.reserve(size_t(E));
  for (int e = 0; e < E; ++e) {
    const std::vector<int>& h = handles[size_t(e)];
    out.handles.insert(out.handles.end(), h.begin(), h.end());
    out.volume.push_back(rest[size_t(e)].volume);
    out.handle_start.push_back(int(out.handles.size()));
    out.max_handles = std::max(out.max_handles, int(h.size()));
  }
  out.gradients.resize(3, Eigen::Index(out.handles.size()));
  for (int e = 0; e < E; ++e)
    out.gradients.middleCols(out.handle_start[size_t(e)], gradients[size_t(e)].cols()) =
        gradients[size_t(e)];
  return out;
}

// Shared by every Simulable of the avatar (SoftAvatar::derived): the table depends on the
// avatar's rest shape, materials and basis only.
const ReducedElasticityTerm::ReducedTets& ReducedElasticityTerm::everyTet() const {
  if (!every_tet_)
    every_tet_ = avatar_.derived<ReducedTets>("reduced_elasticity.every_tet", [&] {
      const VolumetricData& data = avatar_.volumetricData();
      const ElasticTets all = deformableTets(data);
      MatX4i tets(all.size(), 4);
      for (int k = 0; k < all.size(); ++k)
        tets.row(k) = data.templ->mesh.tets.row(all.tets[size_t(k)]);
      auto every = std::make_unique<ReducedTets>(reducedTets(all.tets, tets, all.rest));
      every->rest = all.rest;
      for (const FemMaterialPoint& m : all.materials) every->C_world.push_back(m.C_world);
      return every.release();
    });
  return *every_tet_;
}

std::vector<std::pair<int, int>> ReducedElasticityTerm::handlePairs() const {
  std::vector<std::pair<int, int>> pairs = rest_stiffness_blocks_;
  for (size_t e = 0; e + 1 < handle_start_.size(); ++e)
    for (int s = handle_start_[e]; s < handle_start_[e + 1]; ++s)
      for (int r = handle_start_[e]; r < handle_start_[e + 1]; ++r)
        pairs.emplace_back(handles_[s], handles_[r]);
  return pairs;
}

double ReducedElasticityTerm::elements(int first, int last, double* gz, Mat3* values,
                                       bool psd) const {
  // Per elastic tet, F = I + Z G̃ᵀ on the tet's handles (reducedTetElasticEnergy): gradient
  // and Hessian come straight in the handles' coordinates, one 3 × 3 block per handle pair.
  const bool hessian = values != nullptr;
  double E = 0.0;
  Mat3X Z(3, max_handles_);
  VecX ge(3 * max_handles_);
  MatX He(hessian ? 3 * max_handles_ : 0, hessian ? 3 * max_handles_ : 0);
  for (int e = first; e < last; ++e) {
    const int begin = handle_start_[e], count = handle_start_[e + 1] - begin;
    if (count == 0) continue;
    const int* tet_handles = &handles_[size_t(begin)];
    for (int s = 0; s < count; ++s) Z.col(s) = kin_.u.segment<3>(3 * tet_handles[s]);
    Eigen::Ref<VecX> gradient = ge.head(3 * count);
    Eigen::Ref<MatX> tet_hessian =
        He.topLeftCorner(hessian ? 3 * count : 0, hessian ? 3 * count : 0);
    double w = elements_.weights[e];
    if (rest_stiffness_.size() == 0) {
      E += w *
           reducedTetElasticEnergy(elements_.rest[size_t(e)].volume, elements_.materials[size_t(e)],
                                   gradients_.middleCols(begin, count), Z.leftCols(count),
                                   gz ? &gradient : nullptr, hessian ? &tet_hessian : nullptr, psd);
    } else {
      E += sampleExcess(e, count, w, Z.leftCols(count), gz != nullptr, hessian, psd, gradient,
                        tet_hessian);
      w = 1.0;  // the excess comes weighted
    }
    if (gz)
      for (int s = 0; s < count; ++s)
        Eigen::Map<Vec3>(gz + 3 * tet_handles[s]) += w * gradient.segment<3>(3 * s);
    if (hessian)  // upper triangle of handle pairs (handles_ ascending)
      for (int s = 0; s < count; ++s) {
        for (int r = s; r < count; ++r)
          values[kin_.zzSlot(tet_handles[s], tet_handles[r])] +=
              w * tet_hessian.block<3, 3>(3 * s, 3 * r);
      }
  }
  return E;
}

double ReducedElasticityTerm::sampleExcess(int e, int count, double w,
                                           const Eigen::Ref<const Mat3X>& Z, bool want_gradient,
                                           bool want_hessian, bool psd, Eigen::Ref<VecX> gradient,
                                           Eigen::Ref<MatX> hessian) const {
  // restSplitExcess (fem_material.h) of the tet's energy, with its stored rest Hessian.
  const int m = 3 * count, begin = handle_start_[e];
  const Eigen::Map<const MatX> K(rest_hessians_.data() + rest_hessian_start_[e], m, m);
  const bool derivatives = want_gradient || want_hessian;  // the Hessian needs the gradient
  const double psi = reducedTetElasticEnergy(
      elements_.rest[size_t(e)].volume, elements_.materials[size_t(e)],
      gradients_.middleCols(begin, count), Z, derivatives ? &gradient : nullptr,
      want_hessian ? &hessian : nullptr, psd);
  return restSplitExcess(psi, Eigen::Map<const VecX>(Z.data(), m), K, w,
                         derivatives ? &gradient : nullptr, want_hessian ? &hessian : nullptr, psd,
                         nullptr, rest_floors_[e]);
}

double ReducedElasticityTerm::restStiffness(VecX* g, Mat3* values, int offset) const {
  if (rest_stiffness_.size() == 0) return 0.0;
  // ½ zᵀ K z, K the exact rest stiffness of the subspace (positive definite).
  const VecX Kz = rest_stiffness_ * kin_.u;
  if (g) g->segment(offset + kin_.boneDofs(), Kz.size()) += Kz;
  if (values)
    for (const auto& [a, b] : rest_stiffness_blocks_)
      if (a <= b) values[kin_.zzSlot(a, b)] += rest_stiffness_.block<3, 3>(3 * a, 3 * b);
  return 0.5 * kin_.u.dot(Kz);
}

double ReducedElasticityTerm::evaluate(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                                       FixedHessianBlocks*) const {
  return evaluateElements(kin_, g, H != nullptr, offset, psd, 256);
}

int ReducedElasticityTerm::boundedSamples() const {
  if (rest_stiffness_.size() == 0) return 0;
  int count = 0;
  for (int e = 0; e < elements_.size(); ++e) {
    const int begin = handle_start_[size_t(e)], n = handle_start_[size_t(e) + 1] - begin;
    if (n == 0) continue;
    const Mat3X Z = handleDisplacements(&handles_[size_t(begin)], n);
    const double psi =
        reducedTetElasticEnergy(elements_.rest[size_t(e)].volume, elements_.materials[size_t(e)],
                                gradients_.middleCols(begin, n), Z);
    const Eigen::Map<const MatX> K(rest_hessians_.data() + rest_hessian_start_[size_t(e)], 3 * n,
                                   3 * n);
    bool bounded = false;
    restSplitExcess(psi, Eigen::Map<const VecX>(Z.data(), 3 * n), K, elements_.weights[e], nullptr,
                    nullptr, false, &bounded, rest_floors_[e]);
    count += bounded ? 1 : 0;
  }
  return count;
}

// ---- the Material group -------------------------------------------------------------------

int ReducedElasticityTerm::numMaterialElements() const {
  return elements_.size() + (rest_stiffness_.size() > 0 ? int(everyTet().tet.size()) : 0);
}

int ReducedElasticityTerm::materialElementTet(int e) const {
  return e < elements_.size() ? elements_.tet[size_t(e)]
                              : everyTet().tet[size_t(e - elements_.size())];
}

void ReducedElasticityTerm::materialElementDofs(int e, std::vector<int>& dofs) const {
  const bool sample = e < elements_.size();
  const int k = sample ? e : e - elements_.size();
  const std::vector<int>& start = sample ? handle_start_ : everyTet().handle_start;
  const std::vector<int>& handles = sample ? handles_ : everyTet().handles;
  dofs.clear();
  for (int s = start[size_t(k)]; s < start[size_t(k) + 1]; ++s)
    for (int c = 0; c < 3; ++c) dofs.push_back(kin_.boneDofs() + 3 * handles[size_t(s)] + c);
}

// λᵀ K z = Σ_t V_t ε_t(λ)ᵀ C_world ε_t(z), ε_t = B_t (the tet's linear strain of its handles'
// coordinates): the cotangent of C_world is V_t B_t W_t B_tᵀ for W = Σ λ zᵀ (bilinear), so the
// reverse sweep sums W over steps and passes over the tets once.
void ReducedElasticityTerm::addRestOuter(const VecX& lambda, MatX& W) const {
  if (rest_stiffness_.size() > 0) addSoftStateOuter(lambda, W);
}

// With `shape`, each tet's rest shape too: λᵀ K_t z = V ⟨σ(Z G̃ᵀ), Λ G̃ᵀ⟩ is bilinear, so Σ over
// the steps is a function of T = Σ vec(Λ G̃ᵀ) vec(Z G̃ᵀ)ᵀ (9 × 9), which W_t gives.
void ReducedElasticityTerm::addRestStiffnessProducts(const MatX& W, VecX& values_bar,
                                                     const ShapeChain* shape,
                                                     VecX* beta_bar) const {
  if (rest_stiffness_.size() == 0 || W.size() == 0) return;
  const ReducedTets& all = everyTet();
  const auto form = [&](int t, Mat9& Tt) {
    const int begin = all.handle_start[size_t(t)], n = all.count(t);
    if (n == 0) return false;
    // T[(i, j), (k, l)] = Σ_{s, r} G̃(j, s) G̃(l, r) W(3h_s + i, 3h_r + k): X = W_t (G̃ᵀ ⊗ I₃)
    // first (3n × 9, read from W's blocks), then T = (G̃ ⊗ I₃) X.
    const auto G = all.gradients.middleCols(begin, n);
    MatX X = MatX::Zero(3 * n, 9);
    for (int s = 0; s < n; ++s) {
      const int hs = 3 * all.handles[size_t(begin + s)];
      for (int r = 0; r < n; ++r) {
        const Mat3 Wsr = W.block<3, 3>(hs, 3 * all.handles[size_t(begin + r)]);
        for (int l = 0; l < 3; ++l) X.block<3, 3>(3 * s, 3 * l) += G(l, r) * Wsr;
      }
    }
    Tt.setZero();
    for (int s = 0; s < n; ++s)
      for (int j = 0; j < 3; ++j) Tt.middleRows<3>(3 * j) += G(j, s) * X.middleRows<3>(3 * s);
    return true;
  };
  addRestFormCotangents(all.tet, all.rest, all.C_world, avatar_.volumetricData().templ->mesh.tets,
                        form, values_bar, shape, beta_bar);
}

// The four nodes' displacements u = Z Φᵀ and the direction's λ_u = Λ Φᵀ (Φ: their basis rows on
// the element's handles).
void ReducedElasticityTerm::nodalForm(int e, const Mat3X& Lambda, Mat34& u, Mat34& lu) const {
  const bool sample = e < elements_.size();
  const int k = sample ? e : e - elements_.size();
  const std::vector<int>& start = sample ? handle_start_ : everyTet().handle_start;
  const std::vector<int>& handles = sample ? handles_ : everyTet().handles;
  const int begin = start[size_t(k)], n = start[size_t(k) + 1] - begin;
  const Mat4X Phi = nodeBasis(materialElementNodes(e), &handles[size_t(begin)], n);
  u = handleDisplacements(&handles[size_t(begin)], n) * Phi.transpose();
  lu = Lambda * Phi.transpose();
}

// Every tet of K: V ε(Λ) ε(Z)ᵀ on C_world (through G̃, without the nodes), its rest shape in
// nodal form; a sample: its nodal form (nodal_element_derivatives.h).
void ReducedElasticityTerm::materialElementProducts(int e, const Mat3X& Lambda,
                                                    FemMaterialDerivative* d, Mat34* X_bar) const {
  const bool sample_tet = e < elements_.size();
  const int k = sample_tet ? e : e - elements_.size();
  if (!sample_tet && d) {
    const ReducedTets& all = everyTet();
    const int begin = all.handle_start[size_t(k)], n = all.count(k);
    const Mat3X Z = handleDisplacements(&all.handles[size_t(begin)], n);
    const auto G = all.gradients.middleCols(begin, n);
    d->C_world = all.volume[size_t(k)] * voigtLinearStrain(Lambda * G.transpose()) *
                 voigtLinearStrain(Z * G.transpose()).transpose();
    if (!X_bar) return;
  }
  const std::vector<int>& start = sample_tet ? handle_start_ : everyTet().handle_start;
  if (start[size_t(k) + 1] == start[size_t(k)]) return;
  Mat34 u, lu;
  nodalForm(e, Lambda, u, lu);
  if (sample_tet) {
    sampleProducts(sampleElement(elements_, rest_floors_, e), u, lu, d, X_bar);
    return;
  }
  const ReducedTets& all = everyTet();
  addTetLinearFormRestCotangent(all.rest[size_t(k)], all.C_world[size_t(k)], u, lu, 1.0, *X_bar);
}

Eigen::Vector4i ReducedElasticityTerm::materialElementNodes(int e) const {
  return avatar_.volumetricData().templ->mesh.tets.row(materialElementTet(e)).transpose();
}

}  // namespace flsh::detail
