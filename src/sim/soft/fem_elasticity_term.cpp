#include "sim/soft/fem_elasticity_term.h"

#include <algorithm>

#include "core/first_failure.h"

namespace flsh::detail {

FemElasticityTerm::FemElasticityTerm(const SoftKinematics& kinematics, const MaterialChain& chain,
                                     ElasticElements elements)
    : ElasticityTerm(kinematics, chain), elements_(std::move(elements)) {
  // The blocks: soft-node pairs sharing a tet as (column node, row node), sorted, so that the
  // blocks are column-major.
  const MatX4i& tets = elements_.tets;
  const auto soft = [&](int j) { return kin_.isSoftNode(j); };
  std::vector<std::pair<int, int>> pairs;
  for (Eigen::Index e = 0; e < tets.rows(); ++e)
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b)
        if (soft(tets(e, a)) && soft(tets(e, b))) pairs.emplace_back(tets(e, b), tets(e, a));
  std::sort(pairs.begin(), pairs.end());
  pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
  tet_block_.assign(16 * size_t(tets.rows()), -1);
  for (Eigen::Index e = 0; e < tets.rows(); ++e)
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b) {
        const std::pair<int, int> key(tets(e, b), tets(e, a));  // (column, row)
        if (!soft(key.first) || !soft(key.second)) continue;
        tet_block_[16 * e + 4 * a + b] =
            int(std::lower_bound(pairs.begin(), pairs.end(), key) - pairs.begin());
      }
  const int bone_dofs = kin_.boneDofs();
  block_dofs_.resize(pairs.size());
  for (size_t k = 0; k < pairs.size(); ++k)
    block_dofs_[k] = {bone_dofs + kin_.nodeDof(pairs[k].second),
                      bone_dofs + kin_.nodeDof(pairs[k].first)};
}

double FemElasticityTerm::evaluate(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                                   FixedHessianBlocks* blocks) const {
  const MatX4i& tets = elements_.tets;
  const int T = elements_.size();
  if (g) element_gradients_.resize(T);
  if (H) element_hessians_.resize(T);
  double E = 0.0;
  FirstFailure failure;
#pragma omp parallel for schedule(static) reduction(+ : E) if (T > 2000)
  for (int e = 0; e < T; ++e) {
    double tet = 0.0;  // the reduction's E stays outside the lambda
    failure.run([&] {
      Eigen::Matrix<double, 3, 4> U;
      for (int a = 0; a < 4; ++a) U.col(a) = kin_.nodeDisplacement(kin_.u, tets(e, a));
      const double w = elements_.weights[e];
      tet = w * tetElasticEnergy(elements_.rest[e], elements_.materials[e], U,
                                 g ? &element_gradients_[e] : nullptr,
                                 H ? &element_hessians_[e] : nullptr, psd);
      if (w != 1.0) {
        if (g) element_gradients_[e] *= w;
        if (H) element_hessians_[e] *= w;
      }
    });
    E += tet;
  }
  failure.rethrow();
  if (g) {
    for (int e = 0; e < T; ++e)
      for (int a = 0; a < 4; ++a)
        kin_.addSoftGradient(*g, offset, tets(e, a), element_gradients_[e].segment<3>(3 * a));
  }
  if (H) {
    blocks_.assign(block_dofs_.size(), Mat3::Zero());
    for (int e = 0; e < T; ++e) {
      const int* slots = &tet_block_[16 * size_t(e)];
      for (int a = 0; a < 4; ++a)
        for (int b = 0; b < 4; ++b)
          if (slots[4 * a + b] >= 0)
            blocks_[slots[4 * a + b]] += element_hessians_[e].block<3, 3>(3 * a, 3 * b);
    }
    if (blocks) {
      *blocks = {&block_dofs_, &blocks_, offset};
    } else {
      for (size_t k = 0; k < block_dofs_.size(); ++k)
        addBlock(*H, offset + block_dofs_[k].first, offset + block_dofs_[k].second, blocks_[k]);
    }
  }
  return E;
}

void FemElasticityTerm::materialElementDofs(int e, std::vector<int>& dofs) const {
  dofs.assign(12, -1);
  for (int a = 0; a < 4; ++a) {
    const int j = elements_.tets(e, a);
    if (!kin_.isSoftNode(j)) continue;
    for (int k = 0; k < 3; ++k) dofs[size_t(3 * a + k)] = kin_.boneDofs() + kin_.nodeDof(j) + k;
  }
}

// Λᵀ g_e = w V ⟨P(F), Λ Gᵀ⟩ with G the tet's shape-function gradients.
FemMaterialDerivative FemElasticityTerm::materialElementGradient(int e, const Mat3X& Lambda) const {
  const TetElementRest& rest = elements_.rest[size_t(e)];
  const Mat3X G = reducedShapeGradients(rest, Mat4X::Identity(4, 4));
  Mat3X U(3, 4);
  for (int a = 0; a < 4; ++a) U.col(a) = kin_.nodeDisplacement(kin_.u, elements_.tets(e, a));
  FemMaterialDerivative d;
  addStressMaterialGradient(Mat3::Identity() + U * G.transpose(), elements_.materials[size_t(e)],
                            Lambda * G.transpose(), elements_.weights[e] * rest.volume, d);
  return d;
}

// Λᵀ g_e's rest shape: the element's Dm and volume (addTetGradientRestCotangent).
void FemElasticityTerm::materialElementRestCotangent(int e, const Mat3X& Lambda,
                                                     Mat34& X_bar) const {
  Mat34 U;
  for (int a = 0; a < 4; ++a) U.col(a) = kin_.nodeDisplacement(kin_.u, elements_.tets(e, a));
  addTetGradientRestCotangent(elements_.rest[size_t(e)], elements_.materials[size_t(e)], U, Lambda,
                              elements_.weights[e], X_bar);
}

}  // namespace flsh::detail
