// SimulableAdjointModel: a Simulable (skeleton, FEM or ROM soft skeleton) as an AdjointModel.
//
// State vector: 6 values per bone [t_b (m), r_b (rad, rotation vector of R_b)], then the soft
// DoFs where there are any (Simulable::getState). Increment chart: [δt_b, δω_b] with
// R_b ← exp([δω_b]×) R_b (soft DoFs: their own increments). The chart
// map between them is per bone dt = δt, dr = J_l(r)⁻¹ δω (include/flsh/core/rotation.h).
// Initial velocity: per DoF in the increment chart (m/s, rad/s), q_{−1} = q_0 ⊖ h v_0, i.e.
// t_{−1} = t_0 − h v_t and R_{−1} = exp(−h [v_ω]×) R_0 (Simulable::setVelocity).
#pragma once

#include <memory>
#include <vector>

#include "flsh/diff/adjoint_model.h"
#include "flsh/sim/simulable.h"
#include "flsh/solve/hessian_assembler.h"

namespace flsh {

// The parameter groups, in parameterGroups() order, are the registry's (flsh/sim/sim_parameter.h):
// group k is SimParameter(k), named simParameterInfo(k).name.

class SimulableAdjointModel final : public AdjointModel {
 public:
  /// Throws InputError if the simulable is null, Error if it has kinematic bones (their DoFs
  /// follow targets placed from the parents' predicted state: not differentiated here).
  explicit SimulableAdjointModel(std::shared_ptr<Simulable> simulable);

  Simulable& simulable() const { return *simulable_; }
  /// The groups parameterVJPs computes (empty: all); the others' products are zero. Shape
  /// brings RestJoints and BoneInertia with it (β's chain runs through them).
  void setWantedGroups(const std::vector<SimParameter>& groups);

  int numDofs() const override;
  std::vector<ParameterGroupInfo> parameterGroups() const override;
  std::unique_ptr<StepSnapshot> saveStep() const override;
  void restoreStep(const StepSnapshot& snapshot) override;
  void exactHessian(SpMat& H) const override;
  /// The bones' DoFs (the first Simulable::numBoneDofs()).
  void coarseDofs(std::vector<int>& dofs) const override;
  SpMat previousStateJacobian(int which) const override;
  void parameterJacobians(std::vector<MatX>& out) const override;
  /// Products without matrices (Simulable::getGradientParameterVJPs); the Shape entry holds
  /// only the contact-surface part per step, finishParameterVJPs adds (dJ/dβ)ᵀ p̄_J +
  /// (dI/dβ)ᵀ p̄_I once; the Material entry is zero per step: its products are summed
  /// over the steps and chained once by finishParameterVJPs (Simulable::
  /// accumulateMaterialProducts).
  void previousStatesVJP(const VecX& lambda, VecX& a_n, VecX& a_nm1) const override;
  VecX previousStatesJVP(const VecX& dq_n, const VecX& dq_nm1) const override;
  void parameterVJPs(const VecX& lambda, std::vector<VecX>& out) const override;
  void finishParameterVJPs(std::vector<VecX>& global) const override;
  /// Shape directions are mapped to rest-joint and bone-inertia directions (dJ/dβ β̇,
  /// dI/dβ β̇) plus the contact-surface part: no per-step matrix–matrix chain.
  void parameterJVPs(const std::vector<std::vector<const VecX*>>& directions,
                     std::vector<VecX>& out) const override;
  VecX state() const override;
  VecX incrementToStateTangent(const VecX& dq) const override;
  VecX stateToIncrementTangent(const VecX& ds) const override;
  VecX stateToIncrementCotangent(const VecX& a) const override;
  VecX incrementToStateCotangent(const VecX& a) const override;
  /// The same map at another state vector `state` (e.g. a recorded step's, without restoring
  /// it).
  VecX incrementToStateCotangentAt(const VecX& state, const VecX& a) const;
  /// stateToIncrementCotangent at another state vector `state`.
  VecX stateToIncrementCotangentAt(const VecX& state, const VecX& a) const;
  VecX initialPreviousStateTangent(const VecX& dq0, const VecX& dv0) const override;
  VecX initialPreviousStateCotangent(const VecX& a_previous, VecX& a0) const override;

 private:
  std::shared_ptr<Simulable> simulable_;
  // The Material products of a sweep's steps (Simulable::accumulateMaterialProducts), chained
  // by finishParameterVJPs.
  mutable Simulable::MaterialProducts material_sum_;
  mutable bool material_pending_ = false;
  std::vector<SimParameter> wanted_;  // SimParameter order; all by default
  // exactHessian's assembly: the triplets and fixed block lists summed on a pattern kept across
  // steps (slots cached), as Scene assembles Newton's Hessian.
  mutable HessianAssembler assembler_;
  mutable std::vector<Triplet> triplets_;
  mutable std::vector<FixedHessianBlocks> blocks_;
};

}  // namespace flsh
