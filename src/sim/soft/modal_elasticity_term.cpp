#include "sim/soft/modal_elasticity_term.h"

#include <algorithm>
#include <string>

#include "flsh/core/error.h"
#include "flsh/volume/elastic_tets.h"
#include "flsh/volume/reduced_data.h"
#include "flsh/volume/volumetric_data.h"
#include "volume/subspace_tets.h"

namespace flsh::detail {

ModalElasticityTerm::ModalElasticityTerm(const SoftAvatar& avatar, const SoftKinematics& kinematics,
                                         const MaterialChain& chain, ElasticElements elements)
    : ElasticityTerm(kinematics, chain), avatar_(avatar), elements_(std::move(elements)) {
  const ReducedData& rom = avatar.reducedData();
  const VolumetricData& data = avatar.volumetricData();
  const int T = elements_.size();
  const SpMat rows = rom.basis.transpose();  // φ by rows
  num_modes_ = rom.numModes();
  modal_base_ = 3 * rom.numHandles();
  handle_dofs_.resize(size_t(T));
  handle_D_.resize(size_t(T));
  moves_.assign(size_t(T), 0);
  modal_D_.setZero(9 * Eigen::Index(T), num_modes_);
#pragma omp parallel for schedule(dynamic, 64) if (T > 256)
  for (int e = 0; e < T; ++e) {
    SubspaceTet st =
        subspaceTet(data, rom, rows, elements_.rest[size_t(e)], elements_.tet[size_t(e)]);
    if (st.dofs.empty()) continue;
    moves_[size_t(e)] = 1;
    const int h = int(st.dofs.size()) - num_modes_;  // the handles' entries, then every mode's
    handle_dofs_[size_t(e)].assign(st.dofs.begin(), st.dofs.begin() + h);
    handle_D_[size_t(e)] = st.D.leftCols(h);
    modal_D_.middleRows<9>(9 * Eigen::Index(e)) = st.D.rightCols(num_modes_);
  }
  for (int e = 0; e < T; ++e)
    max_dofs_ = std::max(max_dofs_, int(handle_dofs_[size_t(e)].size()) + num_modes_);
  if (rom.elastic_rest_stiffness.size() == 0) return;
  const int m = kin_.numSoftDofs();
  rest_stiffness_ = rom.elastic_rest_stiffness;
  if (rest_stiffness_.rows() != m || rest_stiffness_.cols() != m)
    throw InputError("Simulable: the avatar's elastic rest stiffness is " +
                     std::to_string(rest_stiffness_.rows()) + " × " +
                     std::to_string(rest_stiffness_.cols()) +
                     ", expected (3·#handles + #modes) square (" + std::to_string(m) + ")");
  rest_tangent_.resize(size_t(T));
  for (int e = 0; e < T; ++e)
    rest_tangent_[size_t(e)] =
        elements_.rest[size_t(e)].volume * restTangent(elements_.materials[size_t(e)]);
  rest_floors_ = elementRestFloors(rom, elements_);
}

void ModalElasticityTerm::elementDofs(int e, std::vector<int>& dofs) const {
  dofs = handle_dofs_[size_t(e)];
  if (!moves_[size_t(e)]) return;
  for (int k = 0; k < num_modes_; ++k) dofs.push_back(modal_base_ + k);
}

std::vector<std::pair<int, int>> ModalElasticityTerm::groupPairs() const {
  std::vector<std::pair<int, int>> pairs;
  const int groups = kin_.numGroups();
  if (rest_stiffness_.size() > 0)
    for (int a = 0; a < groups; ++a)
      for (int b = 0; b < groups; ++b)
        if (!rest_stiffness_.block<3, 3>(3 * a, 3 * b).isZero(0.0)) pairs.emplace_back(a, b);
  std::vector<int> dofs;
  for (int e = 0; e < elements_.size(); ++e) {
    elementDofs(e, dofs);
    for (size_t s = 0; s < dofs.size(); s += 3)
      for (size_t r = 0; r < dofs.size(); r += 3) pairs.emplace_back(dofs[s] / 3, dofs[r] / 3);
  }
  return pairs;
}

Vec9 ModalElasticityTerm::handleStrain(int e) const {
  const std::vector<int>& dofs = handle_dofs_[size_t(e)];
  const MatX& D = handle_D_[size_t(e)];
  Vec9 f = Vec9::Zero();
  for (size_t k = 0; k < dofs.size(); ++k) f += D.col(Eigen::Index(k)) * kin_.u[dofs[k]];
  return f;
}

double ModalElasticityTerm::law(int e, const Vec9& f, Vec9* g9, Mat9* H9, bool psd,
                                bool* bounded) const {
  const double w = elements_.weights[e];
  const double V = elements_.rest[size_t(e)].volume;
  const FemMaterialPoint& material = elements_.materials[size_t(e)];
  const Mat3 F = Mat3::Identity() + Eigen::Map<const Mat3>(f.data());
  const bool derivatives = g9 || H9;  // the split's Hessian needs the gradient
  Mat3 P;
  Mat9 A;
  const double psi =
      V * fungEnergyDensity(F, material, derivatives ? &P : nullptr, H9 ? &A : nullptr, psd);
  if (rest_stiffness_.size() == 0) {
    if (g9) *g9 = (w * V) * Eigen::Map<const Vec9>(P.data());
    if (H9) *H9 = (w * V) * A;
    return w * psi;
  }
  // The excess over the rest quadratic, in the 9 values f (restSplitExcess).
  Vec9 g = Vec9::Zero();
  Mat9 H = Mat9::Zero();
  if (derivatives) g = V * Eigen::Map<const Vec9>(P.data());
  if (H9) H = V * A;
  Eigen::Ref<VecX> g_view = g;
  Eigen::Ref<MatX> H_view = H;
  const double excess =
      restSplitExcess(psi, f, rest_tangent_[size_t(e)], w, derivatives ? &g_view : nullptr,
                      H9 ? &H_view : nullptr, psd, bounded, rest_floors_[e]);
  if (g9) *g9 = g;
  if (H9) *H9 = H;
  return excess;
}

// The modes' part of the elements' f and of the gradient's chain: one product each per chunk of
// elements with their stacked 9 × r blocks (modal_D_), read once from memory while the chunk's
// blocks stay in cache for the second product; the handles' few columns per element.
double ModalElasticityTerm::elements(int first, int last, double* gz, Mat3* values,
                                     bool psd) const {
  constexpr int kChunk = 16;  // 16 · 9 × 72 doubles: 83 kB
  const int r = num_modes_;
  const Eigen::Map<const VecX> zm(kin_.u.data() + modal_base_, r);
  Eigen::Map<VecX> gm(gz ? gz + modal_base_ : nullptr, gz ? r : 0);
  VecX f_chunk(9 * kChunk), g_chunk(9 * kChunk);
  MatX D(values ? 9 : 0, values ? max_dofs_ : 0), HD, He;
  std::vector<int> dofs;
  double E = 0.0;
  for (int begin = first; begin < last; begin += kChunk) {
    const int n = std::min(kChunk, last - begin);
    const auto Dm = modal_D_.middleRows(9 * Eigen::Index(begin), 9 * Eigen::Index(n));
    if (r > 0)
      f_chunk.head(9 * n).noalias() = Dm * zm;
    else
      f_chunk.setZero();
    g_chunk.setZero();
    for (int e = begin; e < begin + n; ++e) {
      if (!moves_[size_t(e)]) continue;
      const Eigen::Index k = 9 * Eigen::Index(e - begin);
      const std::vector<int>& handle_dofs = handle_dofs_[size_t(e)];
      const Vec9 f = f_chunk.segment<9>(k) + handleStrain(e);
      Vec9 g9;
      Mat9 H9;
      E += law(e, f, gz ? &g9 : nullptr, values ? &H9 : nullptr, psd);
      if (gz) {
        g_chunk.segment<9>(k) = g9;
        const MatX& Dh = handle_D_[size_t(e)];
        for (size_t c = 0; c < handle_dofs.size(); ++c)
          gz[handle_dofs[c]] += Dh.col(Eigen::Index(c)).dot(g9);
      }
      if (values) {  // upper triangle of group pairs (dofs ascending, in whole groups)
        elementDofs(e, dofs);
        const int m = int(dofs.size()), h = int(handle_dofs.size());
        D.leftCols(h) = handle_D_[size_t(e)];
        D.middleCols(h, r) = modal_D_.middleRows<9>(9 * Eigen::Index(e));
        HD.noalias() = H9 * D.leftCols(m);
        He.noalias() = D.leftCols(m).transpose() * HD;
        for (int s = 0; s < m; s += 3)
          for (int q = s; q < m; q += 3)
            values[kin_.zzSlot(dofs[size_t(s)] / 3, dofs[size_t(q)] / 3)] += He.block<3, 3>(s, q);
      }
    }
    if (gz && r > 0) gm.noalias() += Dm.transpose() * g_chunk.head(9 * n);
  }
  return E;
}

double ModalElasticityTerm::restStiffness(VecX* g, Mat3* values, int offset) const {
  if (rest_stiffness_.size() == 0) return 0.0;
  const VecX Kz = rest_stiffness_ * kin_.u;
  if (g) g->segment(offset + kin_.boneDofs(), Kz.size()) += Kz;
  if (values) {
    const int groups = kin_.numGroups();
    for (int b = 0; b < groups; ++b)
      for (int a = 0; a <= b; ++a)
        if (kin_.zzSlot(a, b) >= 0)
          values[kin_.zzSlot(a, b)] += rest_stiffness_.block<3, 3>(3 * a, 3 * b);
  }
  return 0.5 * kin_.u.dot(Kz);
}

double ModalElasticityTerm::evaluate(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                                     FixedHessianBlocks*) const {
  return evaluateElements(kin_, g, H != nullptr, offset, psd, 64);
}

int ModalElasticityTerm::boundedSamples() const {
  if (rest_stiffness_.size() == 0) return 0;
  const Eigen::Map<const VecX> zm(kin_.u.data() + modal_base_, num_modes_);
  int count = 0;
  for (int e = 0; e < elements_.size(); ++e) {
    if (!moves_[size_t(e)]) continue;
    const Vec9 f = modal_D_.middleRows<9>(9 * Eigen::Index(e)) * zm + handleStrain(e);
    bool bounded = false;
    law(e, f, nullptr, nullptr, false, &bounded);
    count += bounded ? 1 : 0;
  }
  return count;
}

// ---- the Material and Shape groups ------------------------------------------------------------

const ModalElasticityTerm::EveryTet& ModalElasticityTerm::everyTet() const {
  if (!every_tet_)
    every_tet_ = avatar_.derived<EveryTet>("modal_elasticity.every_tet", [&] {
      ElasticTets all = deformableTets(avatar_.volumetricData());
      auto every = std::make_unique<EveryTet>();
      every->tet = std::move(all.tets);
      every->rest = std::move(all.rest);
      for (const FemMaterialPoint& m : all.materials) every->C_world.push_back(m.C_world);
      // The soft node pairs of the tets (CSR by the first node), and each tet's pair indices.
      const MatX4i& mesh = avatar_.volumetricData().templ->mesh.tets;
      const int n = kin_.numNodes();
      std::vector<std::vector<int>> partners(static_cast<size_t>(n));
      for (int t : every->tet)
        for (int i = 0; i < 4; ++i)
          for (int j = 0; j < 4; ++j)
            if (kin_.isSoftNode(mesh(t, i)) && kin_.isSoftNode(mesh(t, j)))
              partners[size_t(mesh(t, i))].push_back(mesh(t, j));
      every->pair_start.assign(size_t(n) + 1, 0);
      for (int a = 0; a < n; ++a) {
        std::vector<int>& p = partners[size_t(a)];
        std::sort(p.begin(), p.end());
        p.erase(std::unique(p.begin(), p.end()), p.end());
        every->pair_start[size_t(a) + 1] = every->pair_start[size_t(a)] + int(p.size());
        every->pair_node.insert(every->pair_node.end(), p.begin(), p.end());
      }
      every->tet_pairs.resize(every->tet.size());
      for (size_t k = 0; k < every->tet.size(); ++k)
        for (int i = 0; i < 4; ++i)
          for (int j = 0; j < 4; ++j) {
            const int a = mesh(every->tet[k], i), b = mesh(every->tet[k], j);
            int& index = every->tet_pairs[k][size_t(4 * i + j)];
            index = -1;
            if (!kin_.isSoftNode(a) || !kin_.isSoftNode(b)) continue;
            const auto first = every->pair_node.begin() + every->pair_start[size_t(a)];
            const auto last = every->pair_node.begin() + every->pair_start[size_t(a) + 1];
            index = int(std::lower_bound(first, last, b) - every->pair_node.begin());
          }
      return every.release();
    });
  return *every_tet_;
}

int ModalElasticityTerm::numMaterialElements() const {
  return elements_.size() + (rest_stiffness_.size() > 0 ? int(everyTet().tet.size()) : 0);
}

int ModalElasticityTerm::materialElementTet(int e) const {
  return e < elements_.size() ? elements_.tet[size_t(e)]
                              : everyTet().tet[size_t(e - elements_.size())];
}

Eigen::Vector4i ModalElasticityTerm::materialElementNodes(int e) const {
  return avatar_.volumetricData().templ->mesh.tets.row(materialElementTet(e)).transpose();
}

void ModalElasticityTerm::localDofs(int e, std::vector<int>& dofs) const {
  if (e < elements_.size()) {
    elementDofs(e, dofs);
    return;
  }
  // An elastic tet of the rest quadratic has a soft node (deformableTets).
  thread_local std::vector<int> handles;
  kin_.tetHandles(materialElementNodes(e), handles);
  dofs.clear();
  for (int h : handles)
    for (int c = 0; c < 3; ++c) dofs.push_back(3 * h + c);
  for (int k = 0; k < num_modes_; ++k) dofs.push_back(modal_base_ + k);
}

void ModalElasticityTerm::materialElementDofs(int e, std::vector<int>& dofs) const {
  localDofs(e, dofs);
  for (int& d : dofs) d += kin_.boneDofs();
}

void ModalElasticityTerm::nodalForm(int e, const Mat3X& Lambda, Mat34& u, Mat34& lu) const {
  thread_local std::vector<int> dofs;  // per call on the sweeps' threads: no allocation
  thread_local VecX lambda_modes;
  localDofs(e, dofs);
  const int h = int(std::lower_bound(dofs.begin(), dofs.end(), modal_base_) - dofs.begin());
  lambda_modes.resize(num_modes_);
  for (int k = 0; k < num_modes_; ++k) lambda_modes[k] = Lambda((h + k) % 3, (h + k) / 3);
  const Eigen::Vector4i nodes = materialElementNodes(e);
  lu.setZero();
  for (int a = 0; a < 4; ++a) {
    const int j = nodes[a];
    u.col(a) = kin_.nodeDisplacement(kin_.u, j);
    if (!kin_.isSoftNode(j)) continue;
    for (auto* phi = kin_.basisBegin(j); phi != kin_.basisEnd(j); ++phi) {
      const auto at = std::lower_bound(dofs.begin(), dofs.begin() + h, 3 * phi->first);
      lu.col(a) += phi->second * Lambda.col(Eigen::Index(at - dofs.begin()) / 3);
    }
    if (num_modes_ > 0) lu.col(a) += kin_.modeRows(j) * lambda_modes;
  }
}

void ModalElasticityTerm::materialElementProducts(int e, const Mat3X& Lambda,
                                                  FemMaterialDerivative* d, Mat34* X_bar) const {
  if (e < elements_.size() && !moves_[size_t(e)]) return;
  Mat34 u, lu;
  nodalForm(e, Lambda, u, lu);
  if (e < elements_.size()) {
    sampleProducts(sampleElement(elements_, rest_floors_, e), u, lu, d, X_bar);
    return;
  }
  const int k = e - elements_.size();
  if (d) *d = restFormMaterialGradient(everyTet().rest[size_t(k)], u, lu);
  if (X_bar)
    addTetLinearFormRestCotangent(everyTet().rest[size_t(k)], everyTet().C_world[size_t(k)], u, lu,
                                  1.0, *X_bar);
}

void ModalElasticityTerm::addRestOuter(const VecX& lambda, MatX& W) const {
  if (rest_stiffness_.size() > 0) addSoftStateOuter(lambda, W);
}

// T_t = D_t W D_tᵀ, block (l, k) = Σ_{a,b} g_a(l) g_b(k) B_a W B_bᵀ: the products P_a = B_a W
// (3 × m, B_a = ∂u_a/∂z) once per soft node, the 3 × 3 blocks E_ab = P_a B_bᵀ once per soft node
// pair of the tets (P_a's modal columns · Ψ_bᵀ plus the handles' φ columns), then per tet the
// sum of its 16 blocks. (Formed per tet from P̃_l = Σ_a g_a(l) P_a, as before 2026-12-02, the
// same products cost about 3× the flops: each pair lies in ~5 tets.)
void ModalElasticityTerm::addRestStiffnessProducts(const MatX& W, VecX& values_bar,
                                                   const ShapeChain* shape, VecX* beta_bar) const {
  if (rest_stiffness_.size() == 0 || W.size() == 0) return;
  const int n = kin_.numNodes(), m = int(W.cols()), r = num_modes_;
  // P = B W, node j's rows 3j .. 3j + 2 (zero on bone nodes): the modes' share as one product,
  // and E_ab's as coefficient-based 3 × r · r × 3 products. Per node and per pair they went
  // through Eigen's GEMM, which packed its operands for every small product: P 16–25 → 10–14 ms,
  // E 13–21 → 7–10 ms per backward (full-size body, modes 24:72, alternating runs, 2026-12-02).
  RowMatX P(3 * Eigen::Index(n), m);
  if (r > 0)
    P.noalias() = kin_.allModeRows() * W.bottomRows(r);
  else
    P.setZero();
#pragma omp parallel for schedule(static) if (n > 1000)
  for (int j = 0; j < n; ++j) {
    auto Pj = P.middleRows<3>(3 * Eigen::Index(j));
    if (!kin_.isSoftNode(j)) {
      Pj.setZero();
      continue;
    }
    for (auto* phi = kin_.basisBegin(j); phi != kin_.basisEnd(j); ++phi)
      Pj += phi->second * W.middleRows<3>(3 * Eigen::Index(phi->first));
  }
  const EveryTet& all = everyTet();
  const MatX4i& mesh = avatar_.volumetricData().templ->mesh.tets;
  std::vector<Mat3> E(all.pair_node.size());
#pragma omp parallel for schedule(dynamic, 256) if (n > 1000)
  for (int a = 0; a < n; ++a) {
    const auto Pa = P.middleRows<3>(3 * Eigen::Index(a));
    for (int p = all.pair_start[size_t(a)]; p < all.pair_start[size_t(a) + 1]; ++p) {
      const int b = all.pair_node[size_t(p)];
      Mat3& Eab = E[size_t(p)];
      if (r > 0)
        Eab.noalias() = Pa.rightCols(r).lazyProduct(kin_.modeRows(b).transpose());
      else
        Eab.setZero();
      for (auto* phi = kin_.basisBegin(b); phi != kin_.basisEnd(b); ++phi)
        Eab += phi->second * Pa.middleCols<3>(3 * Eigen::Index(phi->first));
    }
  }
  const auto form = [&](int t, Mat9& Tt) {
    const std::array<int, 16>& pairs = all.tet_pairs[size_t(t)];
    const Mat34 G = tetShapeGradients(all.rest[size_t(t)]);
    Tt.setZero();
    bool moves = false;
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) {
        const int p = pairs[size_t(4 * i + j)];
        if (p < 0) continue;
        moves = true;
        const Mat3& Eij = E[size_t(p)];
        for (int l = 0; l < 3; ++l)
          for (int k = 0; k < 3; ++k) Tt.block<3, 3>(3 * l, 3 * k) += (G(l, i) * G(k, j)) * Eij;
      }
    return moves;
  };
  addRestFormCotangents(all.tet, all.rest, all.C_world, mesh, form, values_bar, shape, beta_bar);
}

}  // namespace flsh::detail
