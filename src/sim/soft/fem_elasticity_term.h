// The FEM soft skeleton's elastic energy (ARCHITECTURE.md §4): Σ_e w_e Ψ_e(F_e) over the elastic
// elements, F_e from the nodal displacements of the tet (fem_material.h: orthotropic StVK with
// Fung saturation). It depends on u alone (the tissue's deformation in the unposed frame), so its
// Hessian is one 3 × 3 block per pair of soft nodes sharing a tet, at positions fixed at
// construction. Private to Simulable.
#pragma once

#include <utility>
#include <vector>

#include "sim/soft/elastic_elements.h"
#include "sim/soft/shape_chain.h"

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

  // ---- Shape (β): the rest nodes X̄(β) move each element's Dm and volume
  // (addTetGradientRestCotangent) and its material point, through c(β) and the skin fraction's
  // area and volume (the per-tet material map; frames held) ----
  /// ADDS λᵀ ∂g/∂β (K) into beta_bar at the prepared state.
  void addShapeProducts(const VecX& lambda, const ShapeChain& shape, VecX& beta_bar) const;
  /// ADDS ∂g/∂β dβ into out (numDofs) / ∂g/∂β into J (numDofs × K).
  void addShapeTangent(const VecX& dbeta, const ShapeChain& shape, VecX& out) const;
  void addShapeJacobian(const ShapeChain& shape, MatX& J) const;

 protected:
  // Material elements: the elastic tets; local columns: the tet's four nodes (a bone node has
  // no DoF).
  int numMaterialElements() const override { return elements_.size(); }
  int materialElementTet(int e) const override { return elements_.tet[size_t(e)]; }
  void materialElementDofs(int e, std::vector<int>& dofs) const override;
  FemMaterialDerivative materialElementGradient(int e, const Mat3X& Lambda) const override;

 private:
  /// ∂g/∂β row by row: row(dof, r) with r = ∂g_dof/∂β (K) for every element's local DoF (the
  /// rows of one DoF come in pieces, to be summed).
  template <class Row>
  void shapeRows(const ShapeChain& shape, Row&& row) const;
  /// Element e's share: ADDS into beta_bar its rest nodes' and area/volume's part of
  /// ∂(Λᵀ g_e)/∂β and into values_bar its coefficient values' cotangent.
  void addElementShapeCotangent(int e, const Mat34& Lambda, const ShapeChain& shape,
                                VecX& beta_bar, VecX& values_bar) const;
  ElasticElements elements_;
  // One 3 × 3 block ∂²E/∂u_row∂u_col per pair of soft nodes sharing a tet, at block_dofs_ (row,
  // column DoF relative to the simulable's first DoF; column-major order); element e's local
  // block (a, b) adds into block tet_block_[16 e + 4 a + b] (−1: a bone node).
  std::vector<int> tet_block_;
  std::vector<std::pair<int, int>> block_dofs_;
  mutable std::vector<Vec12> element_gradients_;
  mutable std::vector<Mat12> element_hessians_;
  mutable std::vector<Mat3> blocks_;
};

}  // namespace flsh::detail
