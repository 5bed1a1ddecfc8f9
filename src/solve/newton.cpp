#include "flsh/solve/newton.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "flsh/core/error.h"
#include "solve/coarse_correction.h"
#include "solve/coarse_presolve.h"
#include "solve/preconditioned_cg.h"

namespace flsh {

namespace {

using detail::CgOutcome;
using detail::CgWorkspace;
using detail::preconditionedCg;

// Shifts tried per iteration before giving up on the Newton direction: with the ×10 growth
// this spans 10 orders of magnitude above the first shift.
constexpr int kMaxRegularizationTries = 11;
// An energy may rise by this fraction of its value and still pass the Armijo test: near the
// minimum the predicted decrease drops below the round-off of the energy sum.
constexpr double kEnergyRoundOff = 1e-12;

std::string format(const char* fmt, double a, double b = 0.0) {
  char buffer[256];
  std::snprintf(buffer, sizeof(buffer), fmt, a, b);
  return buffer;
}

void validate(const NewtonOptions& o) {
  const auto bad = [](const std::string& name, const std::string& expected, double value) {
    throw InputError("newtonSolve: NewtonOptions::" + name + " must be " + expected + ", got " +
                     format("%g", value));
  };
  if (o.max_iterations < 0) bad("max_iterations", "≥ 0", o.max_iterations);
  if (!(o.gradient_tolerance >= 0.0) || !std::isfinite(o.gradient_tolerance))
    bad("gradient_tolerance", "finite and ≥ 0", o.gradient_tolerance);
  if (!(o.step_tolerance >= 0.0) || !std::isfinite(o.step_tolerance))
    bad("step_tolerance", "finite and ≥ 0", o.step_tolerance);
  if (o.max_line_search_steps < 0) bad("max_line_search_steps", "≥ 0", o.max_line_search_steps);
  if (!(o.armijo > 0.0 && o.armijo < 1.0)) bad("armijo", "in (0, 1)", o.armijo);
  if (!(o.initial_regularization > 0.0) || !std::isfinite(o.initial_regularization))
    bad("initial_regularization", "finite and > 0", o.initial_regularization);
  const LaggedFactorOptions& lag = o.lagged;
  if (!(lag.cg_relative_tolerance > 0.0 && lag.cg_relative_tolerance < 1.0))
    bad("lagged.cg_relative_tolerance", "in (0, 1)", lag.cg_relative_tolerance);
  if (lag.max_cg_iterations < 1) bad("lagged.max_cg_iterations", "≥ 1", lag.max_cg_iterations);
  if (lag.refactor_after_cg_iterations < 0)
    bad("lagged.refactor_after_cg_iterations", "≥ 0", lag.refactor_after_cg_iterations);
  if (!(lag.reuse_hessian_below >= 0.0) || !std::isfinite(lag.reuse_hessian_below))
    bad("lagged.reuse_hessian_below", "finite and ≥ 0", lag.reuse_hessian_below);
  if (!(o.approximate_max_ratio > 0.0 && o.approximate_max_ratio < 1.0))
    bad("approximate_max_ratio", "in (0, 1)", o.approximate_max_ratio);
  if (o.coarse_presolve.max_iterations < 0)
    bad("coarse_presolve.max_iterations", "≥ 0", o.coarse_presolve.max_iterations);
  const double presolve_tolerance = o.coarse_presolve.relative_tolerance;
  if (!(presolve_tolerance > 0.0 && presolve_tolerance < 1.0))
    bad("coarse_presolve.relative_tolerance", "in (0, 1)", presolve_tolerance);
}

using Clock = std::chrono::steady_clock;

/// Adds the seconds from construction to destruction to `total`.
class ScopedSeconds {
 public:
  explicit ScopedSeconds(double& total) : total_(total), start_(Clock::now()) {}
  ~ScopedSeconds() { total_ += std::chrono::duration<double>(Clock::now() - start_).count(); }
  ScopedSeconds(const ScopedSeconds&) = delete;
  ScopedSeconds& operator=(const ScopedSeconds&) = delete;

 private:
  double& total_;
  Clock::time_point start_;
};

/// Pointers to the stored diagonal of H, inserting explicit zeros where it has none, so that a
/// diagonal shift keeps the sparsity pattern (and the solver's symbolic analysis).
void diagonalPointers(SpMat& H, std::vector<double*>& diagonal) {
  const int n = int(H.rows());
  for (int pass = 0; pass < 2; ++pass) {
    H.makeCompressed();
    diagonal.assign(n, nullptr);
    bool complete = true;
    for (int k = 0; k < n; ++k) {
      const int* begin = H.innerIndexPtr() + H.outerIndexPtr()[k];
      const int* end = H.innerIndexPtr() + H.outerIndexPtr()[k + 1];
      const int* found = std::lower_bound(begin, end, k);
      if (found != end && *found == k)
        diagonal[k] = H.valuePtr() + (found - H.innerIndexPtr());
      else
        complete = false;
    }
    if (complete) return;
    SpMat zero_diagonal(n, n);
    zero_diagonal.setIdentity();
    zero_diagonal.coeffs().setZero();  // structure only: the union keeps H's values
    H = H + zero_diagonal;
  }
  throw Error("newtonSolve: could not store the Hessian diagonal");
}

}  // namespace

void NewtonResult::addCounts(const NewtonResult& other) {
  iterations += other.iterations;
  line_search_steps += other.line_search_steps;
  regularizations += other.regularizations;
  psd_fallbacks += other.psd_fallbacks;
  hessian_evaluations += other.hessian_evaluations;
  approximate_directions += other.approximate_directions;
  approximate_reuses += other.approximate_reuses;
  hessian_reuses += other.hessian_reuses;
  factorizations += other.factorizations;
  cg_iterations += other.cg_iterations;
  coarse_iterations += other.coarse_iterations;
  seconds_energy += other.seconds_energy;
  seconds_gradient += other.seconds_gradient;
  seconds_hessian += other.seconds_hessian;
  seconds_factorization += other.seconds_factorization;
  seconds_solve += other.seconds_solve;
}

NewtonResult newtonSolve(Objective& objective, const NewtonOptions& options, LinearSolver* solver) {
  validate(options);
  NewtonResult result;
  const int n = objective.numDofs();
  std::unique_ptr<LinearSolver> own_solver;
  if (!solver) {
    own_solver = makeLinearSolver(options.linear_solver, n);
    solver = own_solver.get();
  }
  const LaggedFactorOptions& lag = options.lagged;

  // The coarse presolve moves the state first; the tolerance stays relative to the step's
  // start (its coarse gradient there).
  const double presolve_gradient_norm = detail::coarsePresolve(objective, options, result);

  VecX g(n), trial_gradient;
  double energy = 0.0;
  // The gradient at the current state is in g already (Objective::energyAndGradient).
  bool have_gradient = false;
  {
    ScopedSeconds timer(result.seconds_gradient);
    have_gradient = objective.energyAndGradient(energy, g);
  }
  const bool fused = have_gradient;
  if (!fused) {
    ScopedSeconds timer(result.seconds_energy);
    energy = objective.energy();
  }
  result.energy = energy;
  if (n == 0) {
    result.converged = true;
    result.message = "no degrees of freedom";
    return result;
  }
  if (!std::isfinite(energy)) {
    result.message = "the energy is not finite at the initial state; no step taken";
    return result;
  }

  VecX rhs(n), dq(n), trial_step(n);
  SpMat H;
  std::vector<double*> diagonal;
  VecX diagonal_values;
  CgWorkspace cg;
  // The lagged PCG's coarse level (LaggedFactorOptions::coarse_correction), rebuilt from each
  // Hessian PCG runs on.
  std::vector<int> coarse_dofs;
  if (lag.enabled && lag.coarse_correction) objective.coarseDofs(coarse_dofs);
  detail::CoarseCorrection coarse;
  double initial_gradient_norm = 0.0;
  double previous_gradient_norm2 = 0.0;
  double last_step_norm = std::numeric_limits<double>::infinity();
  // The Hessian form held in H, unshifted (−1: none or shifted), so that a failed PCG solve
  // factors the matrix it already assembled.
  int assembled_form = -1;
  bool reused_hessian = false;  // this iteration's PCG ran on the previous iterate's Hessian
  // Directions from the objective's approximate Hessian while they converge fast.
  bool use_approximation = options.approximate_hessian;
  bool last_from_approximation = false;  // the accepted step of the previous iteration
  // The solver holds the approximation's factor from an earlier iteration of this solve, whose
  // directions were accepted in full (approximate_reuse: solve with it again).
  bool held_approximation = false;
  bool last_was_reuse = false;  // the previous iteration's approximate direction reused it

  const auto evaluateHessian = [&](bool psd) {
    {
      ScopedSeconds timer(result.seconds_hessian);
      ++result.hessian_evaluations;
      objective.hessian(H, psd);
      objective.fixKinematic(g, &H);
    }
    if (H.rows() != n || H.cols() != n)
      throw Error("newtonSolve: Objective::hessian returned " +
                  shapeString({long(H.rows()), long(H.cols())}) + ", expected (" +
                  std::to_string(n) + ", " + std::to_string(n) + ")");
    diagonalPointers(H, diagonal);
    assembled_form = psd ? 1 : 0;
  };
  const auto factorize = [&]() {
    ScopedSeconds timer(result.seconds_factorization);
    ++result.factorizations;
    return solver->factorize(H);
  };

  for (int iteration = 0;; ++iteration) {
    {
      ScopedSeconds timer(result.seconds_gradient);
      if (!have_gradient) objective.gradient(g);
      have_gradient = false;
      if (g.size() != n)
        throw Error("newtonSolve: Objective::gradient returned " + std::to_string(g.size()) +
                    " entries, expected numDofs() = " + std::to_string(n));
      objective.fixKinematic(g, nullptr);
    }
    if (!g.allFinite()) {
      result.message = "the gradient is not finite; stopped at the last finite state";
      break;
    }
    const double gradient_norm = g.lpNorm<Eigen::Infinity>();
    result.gradient_norm = gradient_norm;
    if (iteration == 0) initial_gradient_norm = std::max(gradient_norm, presolve_gradient_norm);
    const double gradient_target =
        options.gradient_tolerance * std::max(1.0, initial_gradient_norm);
    if (gradient_norm <= gradient_target) {
      result.converged = true;
      result.message = format("gradient tolerance reached (|g|inf = %.3g)", gradient_norm);
      break;
    }
    // A small step of the approximation's linear rate says little about the gradient: the
    // exact directions decide.
    if (iteration > 0 && last_step_norm <= options.step_tolerance && last_from_approximation) {
      use_approximation = false;
      held_approximation = false;
    } else if (iteration > 0 && last_step_norm <= options.step_tolerance) {
      result.converged = true;
      result.message = format("step tolerance reached (|step|inf = %.3g, |g|inf = %.3g)",
                              last_step_norm, gradient_norm);
      break;
    }
    if (iteration >= options.max_iterations) {
      result.max_iterations_reached = true;
      result.message = format("max_iterations (%g) reached with |g|inf = %.3g",
                              options.max_iterations, gradient_norm);
      break;
    }
    const double gradient_norm2 = g.norm();
    if (last_from_approximation &&
        gradient_norm2 > options.approximate_max_ratio * previous_gradient_norm2) {
      // Converging too slowly: a reused factor is refreshed, a fresh one hands over to the
      // exact directions for the rest of the solve.
      if (!last_was_reuse) use_approximation = false;
      held_approximation = false;
    }
    last_from_approximation = false;
    // The state moved: H, if any, is of the previous iterate (its form, −1: none or shifted).
    const int previous_form = assembled_form;
    assembled_form = -1;
    // Near convergence PCG may run on that previous Hessian (a chord step), once in a row.
    const bool may_reuse =
        lag.reuse_hessian_below > 0.0 && !reused_hessian && iteration > 0 &&
        gradient_norm <= lag.reuse_hessian_below * std::max(1.0, initial_gradient_norm);
    reused_hessian = false;
    // An iteration that uses the PSD form although the exact one was asked counts once.
    bool counted_psd_fallback = false;
    const auto notePsdForm = [&](bool psd) {
      if (psd && options.exact_hessian && !counted_psd_fallback) {
        ++result.psd_fallbacks;
        counted_psd_fallback = true;
      }
    };

    // Attempt 0 may take the lagged-factor PCG direction; if PCG fails (no convergence,
    // non-positive curvature, no descent) the same attempt factors the Hessian it assembled,
    // and if the line search rejects a PCG direction, attempt 1 factors. Either refreshes the
    // lagged factor.
    bool accepted = false;
    double alpha = 1.0;
    // A rejected reused approximation gets a fresh one, then the exact directions: 3 attempts.
    int attempts = 2;
    for (int attempt = 0; attempt < attempts && !accepted; ++attempt) {
      bool have_direction = false;
      bool direction_from_cg = false;
      bool direction_from_approximation = false;
      double diagonal_scale = 1.0;
      const auto scaleOfDiagonal = [&]() {
        diagonal_scale = 0.0;
        for (int k = 0; k < n; ++k) diagonal_scale += std::abs(*diagonal[k]);
        diagonal_scale /= n;
        if (!(diagonal_scale > 0.0) || !std::isfinite(diagonal_scale)) diagonal_scale = 1.0;
      };

      // ---- The objective's approximate Hessian, factored and solved directly (or its factor
      // from an earlier iteration, solved with again).
      bool reused = false;
      if ((attempt == 0 || attempts == 3) && use_approximation) {
        reused = options.approximate_reuse && held_approximation && attempt == 0;
        bool have_approximation = reused;
        if (!reused) {
          ScopedSeconds timer(result.seconds_hessian);
          have_approximation = objective.approximateHessian(H);
          if (have_approximation) objective.fixKinematic(g, &H);
        }
        use_approximation = false;  // unless this direction works out
        held_approximation = false;
        if (have_approximation) {
          if (H.rows() != n || H.cols() != n)
            throw Error("newtonSolve: Objective::approximateHessian returned " +
                        shapeString({long(H.rows()), long(H.cols())}) + ", expected (" +
                        std::to_string(n) + ", " + std::to_string(n) + ")");
          ++result.approximate_directions;
          if (reused) ++result.approximate_reuses;
          bool factored = reused;  // H still holds the approximation the solver factored
          if (!reused) {
            diagonalPointers(H, diagonal);
            assembled_form = -1;  // neither exact form
            factored = factorize();
            if (factored) solver->setFactorStale(false);
          }
          scaleOfDiagonal();
          if (factored) {
            ScopedSeconds timer(result.seconds_solve);
            dq = -g;
            solver->solveInPlace(dq);
            have_direction = direction_from_approximation = dq.allFinite() && g.dot(dq) < 0.0;
          }
        }
      }

      // ---- Lagged factor: PCG on the current Hessian, preconditioned by an earlier factor.
      if (!have_direction && attempt == 0 && lag.enabled && !solver->factorStale() &&
          solver->hasFactor() && solver->factorRows() == n) {
        double forcing = lag.cg_relative_tolerance;
        if (lag.adaptive_forcing && iteration > 0)
          forcing = std::min(forcing, gradient_norm2 / previous_gradient_norm2);
        // No oversolving: a linear residual 10× below the gradient target cannot matter.
        const double residual_tolerance = std::max(forcing * gradient_norm2, 0.1 * gradient_target);
        rhs = -g;
        // The exact form first; if PCG meets non-positive curvature on it, the PSD form.
        for (bool psd = !options.exact_hessian;; psd = true) {
          notePsdForm(psd);
          if (may_reuse && !reused_hessian && previous_form == (psd ? 1 : 0)) {
            reused_hessian = true;  // H stays; a failed PCG assembles this iterate's (form −1)
            ++result.hessian_reuses;
          } else {
            evaluateHessian(psd);
          }
          scaleOfDiagonal();
          int iterations = 0;
          CgOutcome outcome;
          {
            ScopedSeconds timer(result.seconds_solve);
            if (!coarse_dofs.empty()) coarse.build(H, coarse_dofs);  // from this H
            outcome = preconditionedCg(H, rhs, residual_tolerance, lag.max_cg_iterations, *solver,
                                       lag.fast_preconditioner, &coarse, dq, cg, iterations);
          }
          result.cg_iterations += iterations;
          if (iterations > lag.refactor_after_cg_iterations) solver->setFactorStale(true);
          if (outcome == CgOutcome::Converged && dq.allFinite() && g.dot(dq) < 0.0) {
            have_direction = true;
            direction_from_cg = true;
            break;
          }
          const bool indefinite = outcome == CgOutcome::NonPositiveCurvature && !psd;
          if (!indefinite || solver->factorStale()) break;
        }
      }

      // ---- Factored Newton direction: H dq = −g. The exact Hessian first (quadratic
      // convergence); if it is not positive definite, the objective's PSD form; then diagonal
      // shifts until it is.
      if (!have_direction) {
        // With the lag the factor is first of all the preconditioner of later iterations: the
        // PSD form, which cannot fail for want of definiteness (a failed Cholesky of the exact
        // form costs as much as a successful one); PCG tries the exact form again next time.
        const int first_form = options.exact_hessian && !lag.enabled ? 0 : 1;
        for (int form = first_form; form < 2 && !have_direction; ++form) {
          const bool psd = form == 1;
          notePsdForm(psd);
          if (assembled_form != form) evaluateHessian(psd);
          scaleOfDiagonal();
          have_direction = factorize();
        }
        if (!have_direction) {
          diagonal_values.resize(n);
          for (int k = 0; k < n; ++k) diagonal_values[k] = *diagonal[k];
          assembled_form = -1;  // H is shifted from here on
          double shift = options.initial_regularization * diagonal_scale;
          for (int attempt_shift = 0; attempt_shift < kMaxRegularizationTries && !have_direction;
               ++attempt_shift) {
            for (int k = 0; k < n; ++k) *diagonal[k] = diagonal_values[k] + shift;
            ++result.regularizations;
            have_direction = factorize();
            shift *= 10.0;
          }
        }
        solver->setFactorStale(false);
        if (have_direction) {
          ScopedSeconds timer(result.seconds_solve);
          rhs = -g;
          dq = rhs;
          solver->solveInPlace(dq);
          if (!dq.allFinite()) have_direction = false;
        }
      }
      double slope = have_direction ? g.dot(dq) : 0.0;
      if (!have_direction || !(slope < 0.0)) {
        // No usable Newton direction (H singular beyond repair or not finite): scaled steepest
        // descent still decreases the energy and the line search keeps the state finite.
        dq = -g / diagonal_scale;
        slope = g.dot(dq);
      }

      // ---- Backtracking line search (Armijo); non-finite energies count as rejected.
      alpha = 1.0;
      for (int trial = 0;; ++trial) {
        trial_step = alpha * dq;
        objective.push();
        objective.step(trial_step);
        double trial_energy = 0.0;
        if (fused) {
          ScopedSeconds timer(result.seconds_gradient);
          objective.energyAndGradient(trial_energy, trial_gradient);
        } else {
          ScopedSeconds timer(result.seconds_energy);
          trial_energy = objective.energy();
        }
        if (std::isfinite(trial_energy) && trial_energy <= energy + options.armijo * alpha * slope +
                                                               kEnergyRoundOff * std::abs(energy)) {
          if (!objective.discardPushed()) {
            objective.pop();
            objective.step(trial_step);
          }
          energy = trial_energy;
          if (fused) {
            g.swap(trial_gradient);
            have_gradient = true;
          }
          accepted = true;
          break;
        }
        objective.pop();
        if (trial >= options.max_line_search_steps) break;
        alpha *= 0.5;
        ++result.line_search_steps;
      }
      if (direction_from_approximation) {
        // Kept while its full steps are accepted; a cut or rejected reused one is refreshed (a
        // rejected one in this iteration's next attempt); a rejected fresh one gets the exact
        // directions in the next attempt.
        const bool full = accepted && alpha == 1.0;
        use_approximation = full || reused;
        held_approximation = full;
        last_from_approximation = accepted;
        last_was_reuse = reused;
        if (!accepted && reused) attempts = 3;
        continue;
      }
      if (!direction_from_cg) break;  // a factored direction gets no second attempt
    }
    if (!accepted) {
      result.message =
          format("line search found no decrease after %g halvings (|g|inf = %.3g); state kept",
                 options.max_line_search_steps, gradient_norm);
      break;
    }
    previous_gradient_norm2 = gradient_norm2;
    last_step_norm = alpha * dq.lpNorm<Eigen::Infinity>();
    result.iterations = iteration + 1;
  }
  result.energy = energy;
  return result;
}

}  // namespace flsh
