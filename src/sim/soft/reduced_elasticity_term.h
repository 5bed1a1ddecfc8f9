// The ROM soft skeleton's elastic energy (ARCHITECTURE.md §4): the FEM's energy in the subspace
// u = Φ z, summed over the elastic elements (every tet with a soft node, or the elastic
// cubature's sample tets with their weights). Per tet F = I + Z G̃ᵀ on the tet's handles
// (G̃_e = G_e Φ_e, fem_material.h reducedTetElasticEnergy): gradient and Hessian come straight in
// the handles' coordinates, one 3 × 3 block per handle pair, summed into the kinematics' value
// list 1. With the elastic cubature's rest-stiffness split (ReducedData::elastic_rest_stiffness)
// the energy is ½ zᵀ K z (K exact) plus each sample tet's weighted excess over its own rest
// quadratic, bounded below. Private to Simulable.
#pragma once

#include <memory>
#include <utility>
#include <vector>

#include "sim/soft/elastic_elements.h"

namespace flsh::detail {

class ReducedElasticityTerm final : public ElasticityTerm, public ReducedElasticity {
 public:
  ReducedElasticityTerm(const SoftAvatar& avatar, const SoftKinematics& kinematics,
                        const MaterialChain& chain, ElasticElements elements);
  using ElasticityTerm::evaluate;
  /// The Hessian goes into the kinematics' value list 1 (H and blocks are not used). Energy or
  /// gradient alone run on two threads (the tets in halves) from 256 tets.
  double evaluate(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                  FixedHessianBlocks* blocks = nullptr) const override;

  /// Every handle pair (both orders) an element or the rest stiffness couples, for the
  /// kinematics' buildReducedPattern.
  std::vector<std::pair<int, int>> handlePairs() const;
  int numElements() const override { return elements_.size(); }
  /// Elements [first, last): energy returned, gradient added into gz (the handles' 3H entries;
  /// may be null), Hessian blocks summed into `values` (a value list; may be null).
  double elements(int first, int last, double* gz, Mat3* values, bool psd) const override;
  /// Sample tets whose rest-split excess is in its bounded branch at the current state (0
  /// without the split): a diagnostic of the floors (one energy pass over the samples).
  int boundedSamples() const override;
  /// ½ zᵀ K z (0 without the elastic cubature), its gradient and Hessian blocks.
  double restStiffness(VecX* g, Mat3* values, int offset) const override;
  bool hasRestSplit() const override { return rest_stiffness_.size() > 0; }

 protected:
  // Material elements: the sample tets (their excess under the split, or their weighted energy
  // without it), then, with the split, every elastic tet for ½ zᵀ K z (K = Σ_t K_t, K_t =
  // V_t B_tᵀ C_world B_t on the tet's linear strains: λᵀ K_t z is V_t ε(λ)ᵀ C_world ε(z)). Local
  // columns: the tet's handles.
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
  /// Tets in the subspace: each one's handles (ascending) and its shape gradients through the
  /// basis, G̃_e = G_e Φ_e (columns at the same offsets).
  struct ReducedTets {
    std::vector<int> tet;
    std::vector<double> volume;
    std::vector<TetElementRest> rest;  ///< every tet's (everyTet; empty for the samples)
    std::vector<Mat6> C_world;         ///< every tet's material stiffness (everyTet)
    std::vector<int> handle_start, handles;
    Mat3X gradients;
    int max_handles = 0;
    int count(int e) const { return handle_start[size_t(e) + 1] - handle_start[size_t(e)]; }
  };
  ReducedTets reducedTets(const std::vector<int>& tet, const MatX4i& tets,
                          const std::vector<TetElementRest>& rest) const;
  /// Every elastic tet in the subspace (for the Material and Shape groups), built on first use
  /// and shared by the avatar's simulables (SoftAvatar::derived).
  const ReducedTets& everyTet() const;
  /// The current z of n handles (3 × n, column s: handle handles[s]).
  Mat3X handleDisplacements(const int* handles, int n) const;
  /// The four nodes' basis rows on n handles (4 × n): Φ(a, s) = φ_{handles[s]}(nodes[a]).
  Mat4X nodeBasis(const Eigen::Vector4i& nodes, const int* handles, int n) const;
  /// Material element e's nodal displacements u and direction λ_u = Λ Φᵀ.
  void nodalForm(int e, const Mat3X& Lambda, Mat34& u, Mat34& lu) const;
  /// Element e (count handles, cubature weight w, their displacements Z) under the
  /// rest-stiffness split: its weighted excess over its rest quadratic, bounded below;
  /// gradient and Hessian (in the handles' coordinates, weighted) written into the views.
  double sampleExcess(int e, int count, double w, const Eigen::Ref<const Mat3X>& Z,
                      bool want_gradient, bool want_hessian, bool psd, Eigen::Ref<VecX> gradient,
                      Eigen::Ref<MatX> hessian) const;
  const SoftAvatar& avatar_;
  ElasticElements elements_;
  // Element e's handles handles_[handle_start_[e] ..) and its shape gradients through the basis
  // (columns of gradients_ at the same offsets).
  std::vector<int> handle_start_, handles_;
  Mat3X gradients_;
  int max_handles_ = 0;
  // The rest-stiffness split: K of ½ zᵀ K z and the handle pairs whose 3 × 3 block is nonzero;
  // each element's own rest Hessian K̃_e in its handles' coordinates ((3 n_e)² values,
  // column-major, from rest_hessian_start_[e]); the floors.
  MatX rest_stiffness_;
  std::vector<std::pair<int, int>> rest_stiffness_blocks_;
  std::vector<int> rest_hessian_start_;
  VecX rest_hessians_;
  VecX rest_floors_;  // per element: ReducedData::elastic_floors of its sample
  mutable std::shared_ptr<const ReducedTets> every_tet_;
};

}  // namespace flsh::detail
