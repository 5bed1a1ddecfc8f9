// AdjointModel: what the adjoint machinery (tape, reverse and forward sweeps) needs from a
// time-stepped model, independent of its state layout, energies and parameters
// (ARCHITECTURE.md §6). The articulated skeleton plugs in through SimulableAdjointModel; FEM and
// ROM models implement the same interface.
//
// A step n solves g(q; q_n, q_{n−1}, p) = ∇_q E = 0 for q = q_{n+1}. All derivatives are taken
// in the model's increment chart at the current state (for the skeleton: [δt, δω] per bone,
// R ← exp([δω]×) R). Users see STATE VECTORS (for the skeleton: [t, rotation vector] per bone);
// the chart maps below convert tangents and cotangents between the two, so that gradients are
// with respect to the numbers a user passes and reads (torch.autograd.gradcheck on raw inputs).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "flsh/core/types.h"

namespace flsh {

/// One parameter group of a model (e.g. "shape", "pose_targets").
struct ParameterGroupInfo {
  std::string name;
  int size = 0;           ///< values of the group (per step when per_step)
  bool per_step = false;  ///< its own values at every step (tracking targets) or one for all steps
};

/// A saved step of a model (opaque; the model that made it restores it).
class StepSnapshot {
 public:
  virtual ~StepSnapshot() = default;
};

class AdjointModel {
 public:
  virtual ~AdjointModel() = default;

  virtual int numDofs() const = 0;
  /// Parameter groups in a fixed order: parameterJacobians() and the sweeps' results use it.
  virtual std::vector<ParameterGroupInfo> parameterGroups() const = 0;

  // ---- steps -----------------------------------------------------------------------------
  /// Everything the step's gradient g depends on besides model data and the rollout-wide
  /// parameters (current and previous states, time, per-step parameters). restoreStep puts the
  /// model back exactly (bitwise).
  virtual std::unique_ptr<StepSnapshot> saveStep() const = 0;
  virtual void restoreStep(const StepSnapshot& snapshot) = 0;

  // ---- derivatives of the step's total gradient g at the current state ------------------
  /// The EXACT Hessian ∂g/∂q (not a PSD approximation), full symmetric storage, numDofs²;
  /// prescribed (kinematic) DoFs get identity rows/columns.
  virtual void exactHessian(SpMat& H) const = 0;
  /// The DoFs whose rows of the exact Hessian change most from step to step (an avatar's bones:
  /// they rotate with the pose), sorted: the tape's iterative solves give them an exact coarse
  /// level (TapeSolveOptions). Default: none.
  virtual void coarseDofs(std::vector<int>& dofs) const { dofs.clear(); }
  /// ∂g/∂q_n (which = 1) or ∂g/∂q_{n−1} (which = 2), numDofs × numDofs, w.r.t. increments of
  /// that previous state in its own chart.
  virtual SpMat previousStateJacobian(int which) const = 0;
  /// ∂g/∂p for every group (numDofs × size), in parameterGroups() order; `out` is resized.
  virtual void parameterJacobians(std::vector<MatX>& out) const = 0;

  // ---- products (what the sweeps use; the defaults form the matrices above) ----------------
  /// (∂g/∂q_n)ᵀ λ and (∂g/∂q_{n−1})ᵀ λ, numDofs each.
  virtual void previousStatesVJP(const VecX& lambda, VecX& a_n, VecX& a_nm1) const;
  /// ∂g/∂q_n dq_n + ∂g/∂q_{n−1} dq_{n−1}, numDofs.
  virtual VecX previousStatesJVP(const VecX& dq_n, const VecX& dq_nm1) const;
  /// (∂g/∂p)ᵀ λ per group, in parameterGroups() order (`out` is resized). A model may leave
  /// part of a rollout-wide group's product to finishParameterVJPs (e.g. a chain through other
  /// groups that is the same at every step).
  virtual void parameterVJPs(const VecX& lambda, std::vector<VecX>& out) const;
  /// Called once by the reverse sweep with the summed rollout-wide cotangents Σ_t (∂g_t/∂p)ᵀ λ_t
  /// (per group as parameterVJPs returned them) to complete the deferred parts. Default: none.
  virtual void finishParameterVJPs(std::vector<VecX>& global) const { (void)global; }
  /// ∂g/∂p ṗ for several directions at once: directions[d][g] is direction d's change of group g
  /// at this step (empty: zero); out[d] (numDofs) is resized.
  virtual void parameterJVPs(const std::vector<std::vector<const VecX*>>& directions,
                             std::vector<VecX>& out) const;

  // ---- chart maps at the current state -------------------------------------------------------
  /// The state vector (user coordinates), numDofs.
  virtual VecX state() const = 0;
  /// C dq: the change of the state vector for an increment dq (C = d state / d increment).
  virtual VecX incrementToStateTangent(const VecX& dq) const = 0;
  /// C⁻¹ ds: the increment for a change ds of the state vector.
  virtual VecX stateToIncrementTangent(const VecX& ds) const = 0;
  /// Cᵀ a: dL/d(increment) from dL/d(state vector).
  virtual VecX stateToIncrementCotangent(const VecX& a) const = 0;
  /// C⁻ᵀ a: dL/d(state vector) from dL/d(increment).
  virtual VecX incrementToStateCotangent(const VecX& a) const = 0;

  // ---- initial conditions ------------------------------------------------------------------
  // The first step starts from q_0 and q_{−1} = q_0 ⊖ h v_0 (v_0 the initial velocity, in the
  // increment chart per unit time). With the model restored to the initial snapshot (q_n = q_0,
  // q_{n−1} = q_{−1}):
  /// Tangent: increments of q_{−1} for increments dq0 of q_0 and a change dv0 of v_0.
  virtual VecX initialPreviousStateTangent(const VecX& dq0, const VecX& dv0) const = 0;
  /// Cotangent: from dL/d(increment of q_{−1}) adds its share to dL/d(increment of q_0)
  /// (`a0`, in place) and returns dL/dv_0.
  virtual VecX initialPreviousStateCotangent(const VecX& a_previous, VecX& a0) const = 0;
};

}  // namespace flsh
