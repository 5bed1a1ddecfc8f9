// Tape of converged steps and the two sweeps over it (ARCHITECTURE.md §6), generic over the
// model (AdjointModel).
//
// Recording: after step t (t = 1..T) has converged, recordStep() saves the model's step snapshot
// and factors the EXACT Hessian H_t = ∂g_t/∂q_t at the converged state once (Newton's last
// factor belongs to the iterate before its final update, and may be a PSD approximation). The
// factor is a sparse Cholesky L Lᵀ with one fill-reducing ordering shared by all steps; where H_t
// is not positive definite (possible with the exact contact/rotation curvature) an LDLᵀ, and if
// that meets a zero pivot a sparse LU. A singular H_t (not a strict local minimum) is recorded as
// such and the sweeps then throw an Error naming the step.
//
// Reverse sweep (adjoint), with ā_t = dL/dq_t in the increment chart:
//   for t = T..1:  solve H_t λ_t = ā_t;  ā_{t−1} −= (∂g_t/∂q_{t−1})ᵀ λ_t;
//                  ā_{t−2} −= (∂g_t/∂q_{t−2})ᵀ λ_t;  p̄ −= (∂g_t/∂p)ᵀ λ_t
// Forward sweep (tangents), for a direction (ṗ, q̇_0, v̇_0):
//   q̇_t = −H_t⁻¹ (∂g_t/∂q_{t−1} q̇_{t−1} + ∂g_t/∂q_{t−2} q̇_{t−2} + ∂g_t/∂p ṗ_t)
// (one back-substitution per direction per step, with the same factors).
// Both sweeps restore the model to each recorded step to evaluate the Jacobians there, and leave
// it exactly (bitwise) as they found it.
//
// Memory. The snapshots hold every step's converged state, so the factors need not be kept: with
// Tape::Storage::Snapshots each sweep factors step t's exact Hessian when it reaches it (the
// model restored there: the same matrix, the same factor) and keeps one factor at a time. Memory
// then grows with the state (a snapshot per step), not with the factors. Storage::Factors keeps
// them (the skeleton's are small).
//
// Solves with snapshots (TapeSolveOptions). Factoring every step's exact Hessian again is most
// of a sweep's cost on a large FEM body. By default a Snapshots sweep factors only the first
// step it reaches and solves the next ones by preconditioned conjugate gradients on their own
// exact Hessian H_t: the preconditioner is that factor (of a nearby step, in single precision)
// with the model's coarse DoFs (an avatar's bones, exact from H_t) as a second level, the
// balancing two-level preconditioner of Newton's lagged factor (src/solve/coarse_correction.h).
// PCG stops at a relative residual of 1e-12, so the solution is H_t's to that accuracy, as a
// factor's would be to its round-off. A solve that needed many iterations makes the next step
// factor its own H_t (the new preconditioner); a PCG that fails (non-positive curvature: H_t
// indefinite, or no convergence) factors H_t and solves with it directly, as above. Each sweep
// starts from its first step's own factor, so its results do not depend on earlier sweeps.
// FEM walk, 26 k DoFs, 30 steps: 7–12 iterations per step from one factorization
// (docs/benchmarks.md).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "flsh/core/types.h"
#include "flsh/diff/adjoint_model.h"

namespace flsh {

/// Diagnostics of one recorded step.
struct TapeStepInfo {
  bool converged = true;       ///< Newton met its tolerance
  std::string newton_message;  ///< why Newton stopped (NewtonResult::message)
  int newton_iterations = 0;
  /// How Newton got there (NewtonResult): backtracking halvings and iterations whose direction
  /// came from the PSD form. The derivatives are those of the converged state either way.
  int line_search_steps = 0, psd_fallbacks = 0;
  double gradient_norm = 0.0;  ///< ‖g‖∞ at the recorded state
  /// How the exact Hessian was factored: "llt" (positive definite), "ldlt" (indefinite),
  /// "lu" (indefinite, LDLᵀ met a zero pivot) or "singular" (the sweeps refuse this step);
  /// "deferred" until a sweep has factored it (Storage::Snapshots), "pcg" when the last sweep
  /// solved it by PCG on its exact Hessian (TapeSolveOptions).
  std::string factorization;
  /// PCG iterations of the last sweep's solves at this step (every direction of a forward
  /// sweep), 0 where it solved with the step's own factor.
  int cg_iterations = 0;
};

/// How a sweep over a Storage::Snapshots tape solves with each step's exact Hessian H_t
/// ("Solves with snapshots" above). Systems of fewer than 2000 unknowns (the skeleton, the ROM)
/// always factor.
struct TapeSolveOptions {
  /// PCG on H_t preconditioned by a nearby step's factor; false: every step factors its H_t.
  bool iterative = true;
  /// PCG stops when ‖b − H_t x‖₂ ≤ relative_tolerance · ‖b‖₂ (in (0, 1), dimensionless).
  double relative_tolerance = 1e-12;
  /// Iterations (≥ 1) before PCG gives up: the step then factors its H_t and solves directly.
  int max_iterations = 60;
  /// A solve that needed more iterations (≥ 0) than this makes the next step factor its own
  /// H_t, the preconditioner from there on.
  int refactor_after_iterations = 25;
  /// Sweeps with more right-hand sides per step than this (≥ 1; a forward sweep's directions)
  /// factor every step: each direction costs a PCG solve of ~9 iterations, a factor's solves
  /// are cheap. FEM walk, 26 k DoFs: a factorization ~0.1 s, a solve with it ~10 ms, a PCG
  /// solve ~45 ms, so PCG pays for up to 3 directions.
  int max_right_hand_sides = 3;
};

class Tape {
 public:
  Tape();
  ~Tape();
  Tape(Tape&&) noexcept;
  Tape& operator=(Tape&&) noexcept;

  /// What recordStep keeps: each step's factor (Factors, the default) or only its snapshot,
  /// the sweeps factoring each step as they reach it (Snapshots; see "Memory" above). Takes
  /// effect from the next recordInitial.
  enum class Storage { Factors, Snapshots };
  void setStorage(Storage storage);
  Storage storage() const;
  /// Throws InputError on a value out of its range (TapeSolveOptions).
  void setSolveOptions(const TapeSolveOptions& options);
  const TapeSolveOptions& solveOptions() const;

  void clear();
  /// Records the initial conditions: the model with q_n = q_0, q_{n−1} = q_{−1} (before the
  /// first step's preparation). Clears earlier steps.
  void recordInitial(const AdjointModel& model);
  /// Records the converged step at the model's current state (after the solve, before the
  /// state history is shifted). `info.factorization` is filled in here.
  void recordStep(const AdjointModel& model, TapeStepInfo info = {});

  int numSteps() const;  ///< T
  int numDofs() const;
  bool hasInitial() const;
  const TapeStepInfo& stepInfo(int t) const;  ///< t = 1..T
  const StepSnapshot& initialSnapshot() const;
  const StepSnapshot& stepSnapshot(int t) const;  ///< t = 1..T
  /// Starts a sweep (Storage::Snapshots) with `right_hand_sides` solves per step: its first
  /// prepareStep factors its step, so that the sweep's solves do not depend on the sweeps before
  /// it; with more right-hand sides than TapeSolveOptions::max_right_hand_sides, every step.
  void beginSweep(int right_hand_sides = 1) const;
  /// Makes step t's system available to solve(): a no-op when its factor is kept
  /// (Storage::Factors), else the model's exact Hessian at step t (the model restored to step
  /// t's snapshot: the sweeps call it there), factored or kept for PCG (TapeSolveOptions).
  void prepareStep(int t, const AdjointModel& model) const;
  /// Solves H_t x = b (t = 1..T; Storage::Snapshots: after prepareStep(t)): with step t's
  /// factor, or by PCG on H_t (falling back to a factor of H_t).
  VecX solve(int t, const VecX& b) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Gradients of a rollout loss from the reverse sweep. Groups follow model.parameterGroups():
/// `global[g]` (size) for rollout-wide groups, `per_step[g]` (T × size, row t − 1 = step t) for
/// per-step groups; the other entry of each group is empty.
struct AdjointResult {
  std::vector<VecX> global;
  std::vector<RowMatX> per_step;
  VecX initial_state;            ///< dL/d(state vector q_0)
  VecX initial_state_increment;  ///< dL/d(increment of q_0) (the same, in the chart)
  VecX initial_velocity;         ///< dL/dv_0
};

/// Reverse sweep. `state_cotangents` is T × numDofs: row t − 1 = dL/d(state vector after step t).
/// Throws InputError on a wrong shape or non-finite values, Error if the tape is empty or a
/// step's Hessian was singular.
AdjointResult adjointSweep(AdjointModel& model, const Tape& tape,
                           const Eigen::Ref<const RowMatX>& state_cotangents);

/// A direction in parameter and initial-condition space for the forward sweep. Empty members
/// are zero. Groups follow model.parameterGroups() (global: size; per-step: T × size).
struct TangentDirection {
  std::vector<VecX> global;
  std::vector<RowMatX> per_step;
  VecX initial_state;            ///< change of the state vector q_0
  VecX initial_state_increment;  ///< added: increments of q_0 (e.g. through model data)
  VecX initial_velocity;         ///< change of v_0
};

/// Forward sweep: for each direction, the T × numDofs changes of the state vectors (row t − 1 =
/// step t). All directions share each step's Jacobian evaluation and factor. `initial_states`
/// (optional) receives, per direction, the change of the state vector q_0 itself (the
/// direction's initial_state and initial_state_increment together, state-vector layout).
std::vector<RowMatX> tangentSweep(AdjointModel& model, const Tape& tape,
                                  const std::vector<TangentDirection>& directions,
                                  std::vector<VecX>* initial_states = nullptr);

}  // namespace flsh
