// The coarse level of the lagged-factor PCG (not public API; NewtonOptions::lagged,
// LaggedFactorOptions::coarse_correction): an exact solve on a few DoFs of the current
// Hessian, combined with the lagged factor as a balancing (BNN) two-level preconditioner.
//
// Why: the lagged factor is of a Hessian of an earlier state. On an avatar, what changes most
// between factorizations is the bones' rows: their blocks rotate with the pose and sum the
// forces of thousands of nodes, so the bones hold nearly all of the gradient (FEM walk: ‖g‖∞
// over the 144 bone DoFs ~120 N against ~0.5 N over 26 k soft ones). Plain PCG then spends its
// iterations on the stale bone block. With Z the unit columns of the coarse DoFs, E = Zᵀ H Z
// (their block of the current Hessian, dense), Q = Z E⁻¹ Zᵀ and M⁻¹ the lagged factor's solve:
//
//     P = (I − Q H) M⁻¹ (I − H Q) + Q
//
// symmetric positive definite when H and M are (Tang, Nabben, Vuik, Erlangga 2009, "BNN"):
// errors in the coarse span are removed exactly at each application, the factor handles the
// rest. Cost per application beyond M⁻¹: two products with the coarse columns of H and two
// solves with E's Cholesky factor (144 bone DoFs: ~0.5 M entries, 144² values).
#pragma once

#include <Eigen/Cholesky>
#include <vector>

#include "flsh/core/types.h"

namespace flsh::detail {

class CoarseCorrection {
 public:
  /// E = H(dofs, dofs) from H's columns (H symmetric in compressed full storage; dofs sorted,
  /// distinct) and its Cholesky factor. Returns false (the correction then is off) when dofs is
  /// empty or E is not positive definite (the exact Hessian of a bent pose can be indefinite
  /// there); PCG then runs with M⁻¹ alone.
  bool build(const SpMat& H, const std::vector<int>& dofs);
  bool active() const { return active_; }
  /// v ← P v, with `solve(v)` applying M⁻¹ in place.
  template <class Solve>
  void apply(VecX& v, Solve&& solve) const {
    r_ = v;
    coarseSolve(r_, t_);        // t = E⁻¹ Zᵀ r
    subtractColumns(t_, v);     // v = r − H Z t
    solve(v);                   // y = M⁻¹ v
    coarseResidual(r_, v, s_);  // s = Zᵀ (r − H y)
    addCoarse(s_, v);           // y += Z E⁻¹ s
  }

 private:
  void coarseSolve(const VecX& r, VecX& t) const;
  void subtractColumns(const VecX& t, VecX& v) const;
  void coarseResidual(const VecX& r, const VecX& y, VecX& s) const;
  void addCoarse(const VecX& s, VecX& v) const;

  const SpMat* H_ = nullptr;
  std::vector<int> dofs_;
  Eigen::LLT<MatX> E_;
  bool active_ = false;
  bool parallel_ = false;  // the column products on two threads
  mutable VecX r_, t_, s_;
};

}  // namespace flsh::detail
