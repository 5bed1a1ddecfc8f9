// The ROM soft skeleton's elastic energy for the bases with modes (ReducedBasisKind::Modes and
// ModesAndHandles; docs/rom.md): the FEM's energy in the subspace u_j = Σ_h φ_h(j) z_h + Ψ_j z_m,
// summed over the elastic elements (every tet with a soft node, or the elastic cubature's sample
// tets with their weights). Per element F = I + mat(D_e z_e) (volume/subspace_tets.h: D_e 9 × m_e
// on the soft-state entries z_e its nodes move with, every modal coordinate among them), so
// its gradient is V D_eᵀ vec P and its Hessian V D_eᵀ (∂P/∂F) D_e, summed into the kinematics'
// value list 1 by groups of three entries. D_e's modal columns (9 × r, dense) are stacked for
// every element, so a range of elements' f and gradient chain are one matrix–vector product each.
// With the elastic cubature's rest-stiffness split the energy is ½ zᵀ K z (K =
// rom.elastic_rest_stiffness, exact) plus each sample's weighted excess over its own rest
// quadratic, bounded below (restSplitExcess): both are functions of the 9 values of D_e z_e, so the
// excess is formed there (with the rest quadratic V A₀ on them) and chained through D_e, without an
// m_e × m_e rest Hessian per sample. The handle basis alone keeps its cheaper form
// (reduced_elasticity_term.h). Private to Simulable.
//
// The Material and Shape groups (the adjoint's, elastic_elements.h): the material elements are
// the samples, then with the split every elastic tet of ½ zᵀ K z (K = Σ_t V_t D_tᵀ A₀ D_t, the
// basis held: SoftAvatar::withMaterial / withShape recompute K on the same columns). Each takes
// its nodal form (nodal_element_derivatives.h): the nodes' displacements and the local
// direction's through the basis rows. A reverse sweep sums W = Σ λ zᵀ and passes over the tets
// once, each tet's T = D_t W D_tᵀ summed from 3 × 3 blocks B_a W B_bᵀ (B_a = ∂u_a/∂z) formed
// once per soft node pair.
#pragma once

#include <array>
#include <memory>
#include <utility>
#include <vector>

#include "sim/soft/elastic_elements.h"

namespace flsh::detail {

class ModalElasticityTerm final : public ElasticityTerm, public ReducedElasticity {
 public:
  ModalElasticityTerm(const SoftAvatar& avatar, const SoftKinematics& kinematics,
                      const MaterialChain& chain, ElasticElements elements);
  using ElasticityTerm::evaluate;
  /// The Hessian goes into the kinematics' value list 1 (H and blocks are not used). Energy or
  /// gradient alone run on two threads (the elements in halves) from 64 elements.
  double evaluate(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                  FixedHessianBlocks* blocks = nullptr) const override;

  /// Every group pair (both orders) an element or the rest stiffness couples, for the
  /// kinematics' buildReducedPattern.
  std::vector<std::pair<int, int>> groupPairs() const;
  int numElements() const override { return elements_.size(); }
  double elements(int first, int last, double* gz, Mat3* values, bool psd) const override;
  int boundedSamples() const override;
  double restStiffness(VecX* g, Mat3* values, int offset) const override;
  bool hasRestSplit() const override { return rest_stiffness_.size() > 0; }

 protected:
  int numMaterialElements() const override;
  int materialElementTet(int e) const override;
  void materialElementDofs(int e, std::vector<int>& dofs) const override;
  Eigen::Vector4i materialElementNodes(int e) const override;
  void materialElementProducts(int e, const Mat3X& Lambda, FemMaterialDerivative* d,
                               Mat34* X_bar) const override;
  int numProductElements() const override { return elements_.size(); }
  void addRestOuter(const VecX& lambda, MatX& W) const override;

 public:
  void addRestStiffnessProducts(const MatX& rest_outer, VecX& values_bar,
                                const ShapeChain* shape = nullptr,
                                VecX* beta_bar = nullptr) const override;

 private:
  /// Every elastic tet (the split's rest quadratic), built on first use and shared by the
  /// avatar's simulables (SoftAvatar::derived).
  struct EveryTet {
    std::vector<int> tet;
    std::vector<TetElementRest> rest;
    std::vector<Mat6> C_world;
    /// The ordered pairs (a, b) of soft nodes that share one of these tets (a's partners
    /// pair_node[pair_start[a] .. pair_start[a + 1]), ascending, a itself among them), and per
    /// tet its 16 pairs' indices (−1 where a node is not soft): the rest-stiffness products
    /// form each pair's 3 × 3 block once, not once per tet around it.
    std::vector<int> pair_start, pair_node;
    std::vector<std::array<int, 16>> tet_pairs;
  };
  const EveryTet& everyTet() const;
  /// Material element e's soft-state entries (ascending; its handles', then every mode's).
  void localDofs(int e, std::vector<int>& dofs) const;
  /// Material element e's nodal displacements u and the local direction's λ_u (Λ: 3 × its
  /// local columns, localDofs three by three) through the nodes' basis rows.
  void nodalForm(int e, const Mat3X& Lambda, Mat34& u, Mat34& lu) const;
  /// Element e's weighted energy (the excess under the split) at f = vec(F − I), with its
  /// gradient and Hessian in f when asked (restSplitExcess needs the gradient for the Hessian).
  double law(int e, const Vec9& f, Vec9* g9, Mat9* H9, bool psd, bool* bounded = nullptr) const;
  /// The handles' part of element e's f: handle_D_[e] times its entries of the soft state.
  Vec9 handleStrain(int e) const;
  /// Element e's soft-state entries (ascending): its handles', then every mode's.
  void elementDofs(int e, std::vector<int>& dofs) const;
  using RowMatX = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  const SoftAvatar& avatar_;
  ElasticElements elements_;
  int num_modes_ = 0, modal_base_ = 0;         // r, and the modes' first soft-state entry (3H)
  std::vector<char> moves_;                    // per element: a node of it is soft
  std::vector<std::vector<int>> handle_dofs_;  // per element: its handles' entries (ascending)
  std::vector<MatX> handle_D_;                 // per element: 9 × its handles' entries
  RowMatX modal_D_;                            // 9 rows per element: the modes' 9 × r block
  int max_dofs_ = 0;
  MatX rest_stiffness_;             // K (numSoftDofs square), empty without the split
  std::vector<Mat9> rest_tangent_;  // per element with the split: V A₀
  VecX rest_floors_;                // per element with the split
  mutable std::shared_ptr<const EveryTet> every_tet_;
};

}  // namespace flsh::detail
