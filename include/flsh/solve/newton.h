// Newton's method with a backtracking line search on an objective defined over an increment
// chart (rotations are updated multiplicatively), as used by backward Euler written as an
// optimization: q = argmin 1/(2h²)(q−q*)ᵀM(q−q*) + V(q).
#pragma once

#include <string>

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
  /// Symmetric Hessian (full storage). `psd` asks for the positive-semidefinite approximation
  /// (per-term projection / Gauss–Newton contact); false = exact. Newton asks for the exact one
  /// first (NewtonOptions::exact_hessian) and for the PSD one when that is not positive definite.
  virtual void hessian(SpMat& H, bool psd) = 0;
  virtual void step(const VecX& dq) = 0;
  virtual void push() = 0;
  virtual void pop() = 0;
  /// Forgets the last pushed state without restoring it (Newton calls it after accepting a
  /// line-search step, so the stack does not grow). Returns false if not supported; Newton
  /// then falls back to pop() and re-applying the accepted step.
  virtual bool discardPushed() { return false; }
  /// Zeroes kinematic (prescribed) DoFs in g and makes their rows/cols identity in H.
  virtual void fixKinematic(VecX& g, SpMat* H) {}
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
};

struct NewtonResult {
  bool converged = false;
  int iterations = 0;
  double energy = 0.0;
  double gradient_norm = 0.0;  ///< ‖g‖∞ at the end
  int line_search_steps = 0;   ///< backtracking halvings in total
  int regularizations = 0;     ///< Hessian shifts needed
  int psd_fallbacks = 0;       ///< iterations whose exact Hessian was not positive definite
  std::string message;
};

/// Minimizes `objective` from its current state. `solver` (may be null: one is made) is reused
/// across calls so that its symbolic analysis and counters persist. Never produces NaN: a step
/// whose energy is not finite is halved like any rejected step.
NewtonResult newtonSolve(Objective& objective, const NewtonOptions& options = {},
                         LinearSolver* solver = nullptr);

}  // namespace flsh
