// The ROM soft skeleton's elastic energy (ARCHITECTURE.md §4): the FEM's energy in the subspace
// u = Φ z, summed over the elastic elements (every tet with a soft node, or the elastic
// cubature's sample tets with their weights). Per tet F = I + Z G̃ᵀ on the tet's handles
// (G̃_e = G_e Φ_e, fem_material.h reducedTetElasticEnergy): gradient and Hessian come straight in
// the handles' coordinates, one 3 × 3 block per handle pair, summed into the kinematics' value
// list 1. With the elastic cubature's rest-stiffness split (ReducedData::elastic_rest_stiffness)
// the energy is ½ zᵀ K z (K exact) plus each sample tet's weighted excess over its own rest
// quadratic, bounded below. Private to Simulable.
#pragma once

#include <utility>
#include <vector>

#include "sim/soft/elastic_elements.h"

namespace flsh::detail {

class ReducedElasticityTerm final : public ElasticityTerm {
 public:
  ReducedElasticityTerm(const SoftAvatar& avatar, const SoftKinematics& kinematics,
                        ElasticElements elements);
  using ElasticityTerm::evaluate;
  /// The Hessian goes into the kinematics' value list 1 (H and blocks are not used). Energy or
  /// gradient alone run on two threads (the tets in halves) from 256 tets.
  double evaluate(VecX* g, std::vector<Triplet>* H, int offset, bool psd,
                  FixedHessianBlocks* blocks = nullptr) const override;

  /// Every handle pair (both orders) an element or the rest stiffness couples, for the
  /// kinematics' buildReducedPattern.
  std::vector<std::pair<int, int>> handlePairs() const;
  int numElements() const { return elements_.size(); }
  /// Elements [first, last): energy returned, gradient added into gz (the handles' 3H entries;
  /// may be null), Hessian blocks summed into `values` (a value list; may be null).
  double elements(int first, int last, double* gz, Mat3* values, bool psd) const;
  /// ½ zᵀ K z (0 without the elastic cubature), its gradient and Hessian blocks.
  double restStiffness(VecX* g, Mat3* values, int offset) const;

 private:
  /// Element e (count handles, cubature weight w, their displacements Z) under the
  /// rest-stiffness split: its weighted excess over its rest quadratic, bounded below;
  /// gradient and Hessian (in the handles' coordinates, weighted) written into the views.
  double sampleExcess(int e, int count, double w, const Eigen::Ref<const Mat3X>& Z,
                      bool want_gradient, bool want_hessian, bool psd, Eigen::Ref<VecX> gradient,
                      Eigen::Ref<MatX> hessian) const;
  /// The floors c_e of the split's excess (f_e ≥ −c_e q_e) per element: restSplitFloors
  /// (fem_material.h) of K and the sample tets' rest Hessians, so that the energy keeps at
  /// least half of K in every direction.
  VecX restSplitFloors() const;

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
  VecX rest_floors_;
};

}  // namespace flsh::detail
