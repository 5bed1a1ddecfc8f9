// The FEM soft skeleton's elastic energy (ARCHITECTURE.md §4): Σ_e w_e Ψ_e(F_e) over the elastic
// elements, F_e from the nodal displacements of the tet (fem_material.h: orthotropic StVK with
// Fung saturation). It depends on u alone (the tissue's deformation in the unposed frame), so its
// Hessian is one 3 × 3 block per pair of soft nodes sharing a tet, at positions fixed at
// construction. Private to Simulable.
#pragma once

#include <utility>
#include <vector>

#include "sim/soft/elastic_elements.h"

namespace flsh::detail {

class FemElasticityTerm final : public ElasticityTerm {
 public:
  FemElasticityTerm(const SoftKinematics& kinematics, const MaterialChain& chain,
                    ElasticElements elements);
  using ElasticityTerm::evaluate;
  /// `blocks` (may be null): the node-pair blocks are returned through it (positions fixed,
  /// column-major) instead of appended to H.
  double evaluate(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                  FixedHessianBlocks* blocks = nullptr) const override;

 protected:
  // Material elements: the elastic tets; local columns: the tet's four nodes (a bone node has
  // no DoF).
  int numMaterialElements() const override { return elements_.size(); }
  int materialElementTet(int e) const override { return elements_.tet[size_t(e)]; }
  void materialElementDofs(int e, std::vector<int>& dofs) const override;
  Eigen::Vector4i materialElementNodes(int e) const override {
    return elements_.tets.row(e).transpose();
  }
  void materialElementProducts(int e, const Mat3X& Lambda, FemMaterialDerivative* d,
                               Mat34* X_bar) const override;

 private:
  ElasticElements elements_;
  // What the elements' loop reads, in element order: each element's packed tet (its C_world, μ,
  // γ, shape gradients and weighted volume in one place) and its nodes' offsets in the soft
  // state u (−1: a bone node).
  std::vector<PackedTet> packed_;
  std::vector<Eigen::Vector4i> element_u_;
  /// Element e's four nodal displacements (columns; zero at a bone node) at the current u.
  Mat34 elementDisplacements(int e) const;
  // The gradient's gather: soft node k's element slots 4 e + a are node_slots_[node_first_[k],
  // node_first_[k + 1]) in increasing order, and node_u_[k] its offset in u; summed per node
  // on both threads, in the order of one serial pass over the elements.
  std::vector<int> node_first_, node_slots_, node_u_;
  // One 3 × 3 block ∂²E/∂u_row∂u_col per pair of soft nodes sharing a tet, at block_dofs_ (row,
  // column DoF relative to the simulable's first DoF; column-major order); element e's local
  // block (a, b) adds into block tet_block_[16 e + 4 a + b] (−1: a bone node).
  std::vector<int> tet_block_;
  std::vector<std::pair<int, int>> block_dofs_;
  // How the elements' loop sums its local blocks into blocks_ on `threads` threads, each taking
  // a contiguous range of elements (OpenMP's static schedule): a block is summed by the thread of
  // its first element; a local block of a later thread's element goes to deferred_ (in the
  // order of (block, element)) and is added after the loop. Every block then gets the sums of
  // one pass over the elements, bit for bit, without the elements' 12 × 12 Hessians stored.
  struct ScatterPlan {
    int threads = 0;
    std::vector<int> first;           // per thread, its first element (and T at the end)
    std::vector<int> action;          // per local block: 2 k + 1 (first: assign), 2 k (add), −1
                                      // (a bone node), −2 − d (into deferred_[d])
    std::vector<int> deferred_block;  // per deferred local block, its block
  };
  void planScatter(int threads) const;
  mutable ScatterPlan plan_;
  mutable std::vector<Mat3> deferred_;
  mutable std::vector<Vec12> element_gradients_;
  mutable std::vector<Mat3> blocks_;
};

}  // namespace flsh::detail
