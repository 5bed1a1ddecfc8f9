#include "sim/soft/fem_elasticity_term.h"

#include <omp.h>

#include <algorithm>

#include "core/first_failure.h"

namespace flsh::detail {

FemElasticityTerm::FemElasticityTerm(const SoftKinematics& kinematics, const MaterialChain& chain,
                                     ElasticElements elements)
    : ElasticityTerm(kinematics, chain), elements_(std::move(elements)) {
  const int T = elements_.size();
  packed_.resize(size_t(T));
  element_u_.resize(size_t(T));
  int u_size = 0;
  for (int e = 0; e < T; ++e) {
    packed_[size_t(e)] =
        packTet(elements_.rest[size_t(e)], elements_.materials[size_t(e)], elements_.weights[e]);
    for (int a = 0; a < 4; ++a) {
      const int j = elements_.tets(e, a);
      element_u_[size_t(e)][a] = kin_.isSoftNode(j) ? kin_.nodeDof(j) : -1;
      u_size = std::max(u_size, element_u_[size_t(e)][a] + 3);
    }
  }
  // Soft nodes by their offset in u (the gather's order), each with its element slots.
  std::vector<int> count(size_t(u_size / 3), 0), node_of_u(size_t(u_size / 3), -1);
  for (int e = 0; e < T; ++e)
    for (int a = 0; a < 4; ++a)
      if (const int du = element_u_[size_t(e)][a]; du >= 0) ++count[size_t(du / 3)];
  node_first_.assign(1, 0);
  node_u_.clear();
  for (size_t k = 0; k < count.size(); ++k)
    if (count[k] > 0) {
      node_u_.push_back(int(3 * k));
      node_first_.push_back(node_first_.back() + count[k]);
      node_of_u[k] = int(node_u_.size()) - 1;
    }
  node_slots_.resize(size_t(node_first_.back()));
  std::vector<int> fill(node_first_.begin(), node_first_.end() - 1);
  for (int e = 0; e < T; ++e)
    for (int a = 0; a < 4; ++a)
      if (const int du = element_u_[size_t(e)][a]; du >= 0)
        node_slots_[size_t(fill[size_t(node_of_u[size_t(du / 3)])]++)] = 4 * e + a;
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

void FemElasticityTerm::planScatter(int threads) const {
  const int T = elements_.size();
  ScatterPlan& plan = plan_;
  plan.threads = 0;  // set when complete
  // OpenMP's static schedule (libgomp): the first T % threads threads take one element more.
  plan.first.resize(size_t(threads) + 1);
  const int q = T / threads, r = T % threads;
  for (int t = 0; t <= threads; ++t) plan.first[size_t(t)] = q * t + std::min(t, r);
  std::vector<int> owner(block_dofs_.size(), -1);
  std::vector<std::pair<int, int>> deferred;  // (block, local block), in increasing element
  plan.action.assign(tet_block_.size(), -1);
  for (int t = 0; t < threads; ++t)
    for (int e = plan.first[size_t(t)]; e < plan.first[size_t(t) + 1]; ++e)
      for (int l = 16 * e; l < 16 * e + 16; ++l) {
        const int k = tet_block_[size_t(l)];
        if (k < 0) continue;
        if (owner[size_t(k)] < 0) {
          owner[size_t(k)] = t;
          plan.action[size_t(l)] = 2 * k + 1;
        } else if (owner[size_t(k)] == t) {
          plan.action[size_t(l)] = 2 * k;
        } else {
          deferred.emplace_back(k, l);
        }
      }
  std::stable_sort(deferred.begin(), deferred.end(),
                   [](const auto& x, const auto& y) { return x.first < y.first; });
  plan.deferred_block.resize(deferred.size());
  for (size_t d = 0; d < deferred.size(); ++d) {
    plan.deferred_block[d] = deferred[d].first;
    plan.action[size_t(deferred[d].second)] = -2 - int(d);
  }
  deferred_.resize(deferred.size());
  plan.threads = threads;
}

double FemElasticityTerm::evaluate(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                                   FixedHessianBlocks* blocks) const {
  const int T = elements_.size();
  if (g) element_gradients_.resize(size_t(T));
  if (H) blocks_.resize(block_dofs_.size());
  double E = 0.0;
  FirstFailure failure;
  // The elements in contiguous ranges, one per thread (as `omp for schedule(static)`); each
  // element's Hessian goes straight into the blocks (see ScatterPlan).
#pragma omp parallel reduction(+ : E) if (T > 2000)
  {
    const int threads = omp_get_num_threads(), t = omp_get_thread_num();
#pragma omp single
    failure.run([&] {
      if (H && plan_.threads != threads) planScatter(threads);
    });
    // After the single's barrier the plan is ready (or failed: nothing to do).
    const bool planned = !H || plan_.threads == threads;
    const int begin = (T / threads) * t + std::min(t, T % threads);
    const int end = begin + T / threads + (t < T % threads ? 1 : 0);
    for (int e = begin; planned && e < end; ++e) {
      double tet = 0.0;  // the reduction's E stays outside the lambda
      failure.run([&] {
        Mat12 He;
        tet =
            tetElasticEnergy(packed_[size_t(e)], elementDisplacements(e),
                             g ? &element_gradients_[size_t(e)] : nullptr, H ? &He : nullptr, psd);
        if (!H) return;
        const int* action = &plan_.action[16 * size_t(e)];
        for (int b = 0; b < 4; ++b)
          for (int a = 0; a < 4; ++a) {
            const int act = action[4 * a + b];
            if (act == -1) continue;
            const auto local = He.block<3, 3>(3 * a, 3 * b);
            if (act < 0)
              deferred_[size_t(-2 - act)] = local;
            else if (act & 1)
              blocks_[size_t(act >> 1)] = Mat3::Zero() + local;
            else
              blocks_[size_t(act >> 1)] += local;
          }
      });
      E += tet;
    }
  }
  failure.rethrow();
  if (g) {
    // Per soft node, its elements' shares in element order (as one serial pass), on two threads.
    const int nodes = int(node_u_.size());
    double* out = g->data() + offset + kin_.boneDofs();
#pragma omp parallel for schedule(static) if (nodes > 2000)
    for (int k = 0; k < nodes; ++k) {
      Eigen::Map<Vec3> sum(out + node_u_[size_t(k)]);
      for (int i = node_first_[size_t(k)]; i < node_first_[size_t(k) + 1]; ++i) {
        const int slot = node_slots_[size_t(i)];
        sum += element_gradients_[size_t(slot >> 2)].segment<3>(3 * (slot & 3));
      }
    }
  }
  if (H) {
    for (size_t d = 0; d < deferred_.size(); ++d)
      blocks_[size_t(plan_.deferred_block[d])] += deferred_[d];
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
    const int du = element_u_[size_t(e)][a];
    if (du < 0) continue;
    for (int k = 0; k < 3; ++k) dofs[size_t(3 * a + k)] = kin_.boneDofs() + du + k;
  }
}

Mat34 FemElasticityTerm::elementDisplacements(int e) const {
  const Eigen::Vector4i& du = element_u_[size_t(e)];
  Mat34 U;
  for (int a = 0; a < 4; ++a) U.col(a) = du[a] < 0 ? Vec3::Zero() : Vec3(kin_.u.segment<3>(du[a]));
  return U;
}

// Λᵀ g_e = w V ⟨P(F), Λ Gᵀ⟩ with G the tet's shape-function gradients; its rest shape: the
// element's Dm and volume (addTetGradientRestCotangent).
void FemElasticityTerm::materialElementProducts(int e, const Mat3X& Lambda,
                                                FemMaterialDerivative* d, Mat34* X_bar) const {
  const TetElementRest& rest = elements_.rest[size_t(e)];
  const Mat34 U = elementDisplacements(e);
  if (d) {
    const Mat34 G = tetShapeGradients(rest);
    addStressMaterialGradient(Mat3::Identity() + U * G.transpose(), elements_.materials[size_t(e)],
                              Lambda * G.transpose(), elements_.weights[e] * rest.volume, *d);
  }
  if (X_bar)
    addTetGradientRestCotangent(rest, elements_.materials[size_t(e)], U, Lambda,
                                elements_.weights[e], *X_bar);
}

}  // namespace flsh::detail
