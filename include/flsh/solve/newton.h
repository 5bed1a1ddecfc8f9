// Newton's method with a backtracking line search on an objective defined over an increment
// chart (rotations are updated multiplicatively), as used by backward Euler written as an
// optimization: q = argmin 1/(2h²)(q−q*)ᵀM(q−q*) + V(q).
#pragma once

#include <string>
#include <vector>

#include "flsh/core/types.h"
#include "flsh/solve/linear_solver.h"

namespace flsh {

/// What Newton minimizes. Gradient and Hessian are with respect to an increment dq applied by
/// step(dq) at the current state; push()/pop() save and restore the state (a stack).
class Objective {
 public:
  virtual ~Objective() = default;
  virtual int numDofs() const = 0;
  virtual double energy() = 0;
  virtual void gradient(VecX& g) = 0;  ///< resized to numDofs()
  /// The energy and, from the same pass, the gradient (g resized to numDofs()), for objectives
  /// whose gradient pass gives the energy almost for free. Returns false if not supported (the
  /// default; nothing is evaluated). Newton then asks it at the initial state and at line-search
  /// trial states, whose gradient is the next iteration's when the trial is accepted (a rejected
  /// trial's gradient is wasted), instead of energy() there and gradient() at each iteration.
  virtual bool energyAndGradient(double& energy, VecX& g) { return false; }
  /// Symmetric Hessian (full storage). `psd` asks for the positive-semidefinite approximation
  /// (per-term projection / Gauss–Newton contact); false = exact. Newton asks for the exact one
  /// first (NewtonOptions::exact_hessian) and for the PSD one when that is not positive definite.
  virtual void hessian(SpMat& H, bool psd) = 0;
  /// A cheaper approximation of the Hessian (full storage, positive definite where the model
  /// is; e.g. the ROM's constant soft–soft block), for Newton's directions while they converge
  /// fast (NewtonOptions::approximate_hessian). Returns false when the objective has none (the
  /// default; H untouched).
  virtual bool approximateHessian(SpMat& H) { return false; }
  virtual void step(const VecX& dq) = 0;
  virtual void push() = 0;
  virtual void pop() = 0;
  /// Forgets the last pushed state without restoring it (Newton calls it after accepting a
  /// line-search step, so the stack does not grow). Returns false if not supported; Newton
  /// then falls back to pop() and re-applying the accepted step.
  virtual bool discardPushed() { return false; }
  /// Zeroes kinematic (prescribed) DoFs in g and makes their rows/cols identity in H.
  virtual void fixKinematic(VecX& g, SpMat* H) {}
  /// The DoFs of the lagged-factor PCG's coarse level (LaggedFactorOptions::coarse_correction),
  /// sorted and distinct: a few (up to a few hundred) where the Hessian changes most between
  /// factorizations, e.g. an avatar's bones. Default: none.
  virtual void coarseDofs(std::vector<int>& dofs) const { dofs.clear(); }
  /// The objective over the coarse DoFs alone, every other DoF held at its current value, for
  /// Newton's coarse presolve (NewtonOptions::coarse_presolve): the energy up to a constant and
  /// its gradient over coarseDofs() (g resized to their number, in their order; kinematic DoFs
  /// zeroed as fixKinematic does). A scene's: its avatars' bones with the soft tissue held, whose
  /// elastic energy is then constant and not evaluated. Returns false (the default; nothing
  /// evaluated) when the objective has no such form: then no presolve.
  virtual bool coarseEnergyAndGradient(double& energy, VecX& g) { return false; }
  /// The coarse DoFs' block of the Hessian (exact or psd as hessian()), dense, full storage,
  /// kinematic rows and columns those of the identity. Called only where coarseEnergyAndGradient
  /// returns true.
  virtual void coarseHessian(MatX& H, bool psd) {}
  /// A linear solver the coarse presolve may keep from one call to the next (with its
  /// symbolic analysis of the coarse block's sparsity), owned by the objective and used for
  /// nothing else; nullptr (the default): the presolve makes one per call.
  virtual LinearSolver* coarseSolver() { return nullptr; }
};

/// Newton directions from conjugate gradients preconditioned with the Cholesky factor of an
/// earlier Hessian (of this call or of an earlier call with the same solver: the lag spans time
/// steps), refactoring only when that preconditioner stops paying off. For large FEM Hessians,
/// where one factorization costs as much as ~20 PCG iterations (25k DoFs: ~0.5 s against
/// ~0.02 s for a pair of triangular solves plus H·p).
/// Per iteration: if the solver holds a factor of numDofs() unknowns (any pattern: a factor of
/// an earlier matrix is only a preconditioner) and no PCG solve marked it stale, PCG on the
/// current Hessian. If PCG does not reach the forcing term within max_cg_iterations, meets
/// pᵀHp ≤ 0, or its direction is not a descent direction or fails the line search, the
/// iteration factors the Hessian it assembled and solves directly (the usual PSD fallback and
/// regularization apply), and that factor becomes the lagged one. Factors are always of the PSD
/// form here: the factor is first of all the preconditioner of later iterations, and a failed
/// Cholesky of an indefinite exact form costs as much as a successful one. With exact_hessian,
/// PCG runs on the exact Hessian at every iteration; where it meets non-positive curvature,
/// that iteration runs PCG on the PSD form instead. Trying the exact form at every iteration
/// keeps quadratic convergence where the PSD form overestimates the curvature (compressed FEM
/// tissue). Measured on the walking full body (fem_benchmark 30): PCG on the PSD form alone, 7.1
/// Newton iterations and 1.0 factorizations per step (up to 24 iterations at heel strikes, the
/// gradient shrinking by ~0.8 per iteration); exact first at every iteration with refreshes of
/// the exact form where positive definite, 5.1 and 1.4 (failed exact factorizations included);
/// as described (PSD refreshes), 5.2 and 1.1.
/// Measured on the 1536-DoF spring network of tests/solve/newton_lagged_test.cpp over 10
/// twisting steps at tolerance 1e-9 (before the exact-first rule): plain Newton 40 iterations /
/// 40 factorizations; lagged 42 iterations / 2 factorizations / 219 PCG iterations (~5 per
/// direction), 3.5× less time.
/// Note for the adjoint: the factor left in the solver may be of an earlier Hessian, and with
/// exact_hessian it is of the PSD form.
struct LaggedFactorOptions {
  /// false: every iteration factors its Hessian (plain Newton).
  bool enabled = false;
  /// Forcing term η_max in (0, 1), dimensionless: PCG stops when ‖H d + g‖₂ ≤ η ‖g‖₂ (or when
  /// that residual is 10× below the convergence target, where more accuracy cannot matter).
  /// 1e-2: 1e-1 and 5e-2 took up to 40 % more Newton iterations (Hessian assemblies) for about
  /// the same PCG iterations; 1e-3 took 12–20 % more PCG iterations for no fewer Newton ones.
  double cg_relative_tolerance = 1e-2;
  /// Eisenstat–Walker-like η_k = min(η_max, ‖g_k‖₂/‖g_{k−1}‖₂): tighter as Newton converges,
  /// which keeps the superlinear rate. Same cost as a fixed η at tolerance 1e-6, up to 11 %
  /// fewer Newton iterations at 1e-9.
  bool adaptive_forcing = true;
  /// PCG iterations (≥ 1) per Newton direction before giving up and factoring: 25 ≈ the cost of
  /// one factorization at 25k DoFs, so a failed PCG at most doubles that iteration's cost.
  int max_cg_iterations = 25;
  /// When a PCG solve needed more than this many iterations (≥ 0), the next direction factors
  /// its Hessian instead: the lagged factor has gone stale. Cost (factorizations + PCG
  /// iterations / 20) on the test problem for refactor_after / max_cg = 8/15, 10/25, 20/40,
  /// 30/60: 9.1, 9.5, 13.8, 13.8 (moderate steps) and 51.5, 51.9, 67.7, 77.2 (large steps).
  int refactor_after_cg_iterations = 10;
  /// PCG applies the factor through LinearSolver::preconditionInPlace (CHOLMOD: a float copy of
  /// the factor, triangular solves split over the threads) instead of the exact double-precision
  /// solve. The preconditioner is an approximation anyway (a lagged factor); the float copy
  /// only moves it by ~1e-7 relative. FEM walk (27 k DoFs): the same Newton and PCG iteration
  /// counts, a PCG iteration ~9 → ~4 ms (docs/benchmarks.md). The dense solver (ROM) applies a
  /// float copy of its LLᵀ factor: the same PCG iteration counts, solves ~1.5 → ~1.2 ms per
  /// walking step.
  bool fast_preconditioner = true;
  /// Near convergence, PCG may run on the previous iterate's Hessian instead of assembling this
  /// one's (a chord step; at most one in a row, and only in the form that Hessian has): when
  /// ‖g‖∞ ≤ reuse_hessian_below · max(1, ‖g₀‖∞) (dimensionless, ≥ 0; 0: never). If that PCG
  /// fails or its step is rejected, the iteration assembles its own Hessian as usual.
  double reuse_hessian_below = 0.0;
  /// PCG's preconditioner gets a coarse level: an exact solve on the objective's coarse DoFs
  /// (Objective::coarseDofs; a scene's: every avatar's bones) with their block of the current
  /// Hessian, combined with the lagged factor as a balancing two-level preconditioner
  /// (src/solve/coarse_correction.h). The lagged factor goes stale mostly in the bones' rows,
  /// which rotate with the pose and carry nearly all of the gradient. FEM walk, 30 steps:
  /// 23.2 → 5.6 PCG iterations and 0.40 → 0 factorizations per step, the same Newton
  /// iterations (docs/benchmarks.md). Off when the objective names no coarse DoFs or their
  /// block is not positive definite (then PCG on the factor alone).
  bool coarse_correction = false;
};

/// Newton iterations on the objective's coarse DoFs alone before those on every DoF
/// (Objective::coarseEnergyAndGradient; a scene's: its avatars' bones, the soft tissue held).
/// The bones carry a step's large rotations, whose nonlinearity otherwise costs whole
/// iterations on every DoF (and line-search cuts); on the bones alone an iteration costs a
/// fraction of one on every DoF (no elastic term, a dense 6 × bones system). The presolve
/// decreases the same energy, so the solve on every DoF starts lower and converges to the same
/// minimum; its gradient tolerance stays relative to the gradient at the start of the presolve
/// (the larger of the coarse one there and the whole one after). FEM jumping jacks: 4.9 → 3.x
/// iterations on every DoF per step (docs/benchmarks.md).
struct CoarsePresolveOptions {
  /// At most this many iterations (0: no presolve; also none where the objective has no coarse
  /// form).
  int max_iterations = 0;
  /// The presolve stops when ‖g_c‖∞ ≤ relative_tolerance · max(1, ‖g_c,0‖∞) on the coarse
  /// gradient g_c (dimensionless, in (0, 1)). FEM, 30 steps: 1e-4 against 1e-3 takes 0.4–0.9
  /// more iterations on the bones and 0.03–0.1 fewer on every DoF, 2–10 % faster.
  double relative_tolerance = 1e-4;
};

struct NewtonOptions {
  int max_iterations = 30;
  /// Converged when ‖g‖∞ ≤ gradient_tolerance · max(1, ‖g₀‖∞) …
  /// (Measured on the walking SMPL-size avatar at h = 1/60 s with the exact Hessian: 1e-6 ends
  /// 7e-9 m/rad from a 1e-13 solve after one step and within 2e-5 over 200 steps, in ~3.2
  /// iterations; 1e-4 saves only 0.3 iterations for 50× the error, so 1e-6 stays.)
  double gradient_tolerance = 1e-6;
  /// … or when the accepted step ‖dq‖∞ ≤ step_tolerance (m or rad).
  double step_tolerance = 1e-9;
  int max_line_search_steps = 25;
  double armijo = 1e-4;  ///< sufficient-decrease constant
  /// Diagonal shift added (×10 per retry) when the Hessian is not positive definite, relative
  /// to the mean diagonal.
  double initial_regularization = 1e-8;
  LinearSolverType linear_solver = LinearSolverType::Auto;
  /// Newton direction from the exact Hessian (Objective::hessian(H, false)) while it is
  /// positive definite, else from the PSD form (then diagonal shifts). The exact form converges
  /// quadratically: ~3.2 instead of ~4.2 iterations per walking step at the same tolerance, and
  /// 5 instead of 18 for a 1e-13 solve. false: always the PSD form.
  bool exact_hessian = true;
  /// Directions from Objective::approximateHessian while they converge fast: each iteration
  /// factors the approximation and solves with it directly (the energy and gradient stay exact,
  /// so the step converges to the same minimum, at a linear rate). The rest of the solve takes
  /// the directions above (exact form, lagged factor) from the first iteration where the
  /// approximation's step was cut by the line search, its factorization failed, or ‖g‖₂ shrank
  /// by less than approximate_max_ratio; with the lag its factor then preconditions PCG. A step
  /// of the approximation below step_tolerance does not end the solve (its rate is linear): the
  /// exact directions follow. Off by
  /// default; SceneOptions::reduced_newton turns it on (the ROM's constant soft–soft block).
  bool approximate_hessian = false;
  /// Largest ‖g_{k+1}‖₂ / ‖g_k‖₂ (in (0, 1)) after an approximate direction that keeps using
  /// the approximation.
  double approximate_max_ratio = 0.5;
  /// Solve with the approximation's factor of an earlier iteration of the same solve while its
  /// full steps are accepted and shrink ‖g‖₂ by approximate_max_ratio (a chord method: no
  /// assembly, no factorization); a reused factor that does not is refreshed once before the
  /// exact directions take over.
  bool approximate_reuse = true;
  /// Lagged factor + PCG (off by default: every iteration factors).
  LaggedFactorOptions lagged;
  /// Iterations on the coarse DoFs first (off by default; on in softTissueNewtonDefaults).
  CoarsePresolveOptions coarse_presolve;
};

struct NewtonResult {
  bool converged = false;
  /// The solve stopped at NewtonOptions::max_iterations (converged false, its last accepted
  /// iterate kept): a failure for a tolerance, the intended end for an iteration budget (the
  /// real-time preset, flsh/io/presets.h).
  bool max_iterations_reached = false;
  int iterations = 0;
  double energy = 0.0;
  double gradient_norm = 0.0;  ///< ‖g‖∞ at the end
  int line_search_steps = 0;   ///< backtracking halvings in total
  int regularizations = 0;     ///< Hessian shifts needed
  /// Iterations whose direction came from the PSD form although exact_hessian was asked: the
  /// exact form was not positive definite, or (lagged factor) the iteration refreshed the
  /// factor, which is then always of the PSD form.
  int psd_fallbacks = 0;
  int hessian_evaluations = 0;  ///< Objective::hessian calls (either form)
  /// Iterations whose direction came from Objective::approximateHessian (its calls count here,
  /// not in hessian_evaluations; their time in seconds_hessian).
  int approximate_directions = 0;
  /// Of those, the ones solved with an earlier iteration's factor (approximate_reuse).
  int approximate_reuses = 0;
  /// Iterations whose PCG ran on the previous iterate's Hessian (lagged.reuse_hessian_below).
  int hessian_reuses = 0;
  /// Numeric factorizations in this call (regularization retries included).
  int factorizations = 0;
  int cg_iterations = 0;  ///< PCG iterations in total (lagged factor only)
  /// Iterations of the coarse presolve (NewtonOptions::coarse_presolve; not in `iterations`,
  /// their dense coarse Hessians not in hessian_evaluations; their time in the seconds below).
  int coarse_iterations = 0;
  /// Wall-clock seconds (steady clock) in this call: objective energies (line search included),
  /// gradients (Objective::energyAndGradient's passes count here, with the energy they give),
  /// Hessians (assembly; fixKinematic counts with its form), numeric
  /// factorizations (symbolic analyses included), and solves (triangular solves + PCG).
  double seconds_energy = 0.0;
  double seconds_gradient = 0.0;
  double seconds_hessian = 0.0;
  double seconds_factorization = 0.0;
  double seconds_solve = 0.0;
  std::string message;

  /// Adds `other`'s counters and timings (iterations through seconds_solve) to this one's, for
  /// totals over many solves; converged, energy, gradient_norm and message stay as they are.
  void addCounts(const NewtonResult& other);
};

/// Minimizes `objective` from its current state. `solver` (may be null: one is made) is reused
/// across calls so that its symbolic analysis, counters and (with options.lagged) its factor
/// persist. With the lag on, the factor held at the end may be of an earlier Hessian. Never
/// produces NaN: a step whose energy is not finite is halved like any rejected step.
NewtonResult newtonSolve(Objective& objective, const NewtonOptions& options = {},
                         LinearSolver* solver = nullptr);

}  // namespace flsh
