#include "flsh/solve/newton.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "flsh/core/error.h"

namespace flsh {

namespace {

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
}

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

NewtonResult newtonSolve(Objective& objective, const NewtonOptions& options, LinearSolver* solver) {
  validate(options);
  NewtonResult result;
  const int n = objective.numDofs();
  std::unique_ptr<LinearSolver> own_solver;
  if (!solver) {
    own_solver = makeLinearSolver(options.linear_solver, n);
    solver = own_solver.get();
  }

  double energy = objective.energy();
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

  VecX g(n), rhs(n), dq(n), trial_step(n);
  SpMat H;
  std::vector<double*> diagonal;
  VecX diagonal_values;
  double initial_gradient_norm = 0.0;
  double last_step_norm = std::numeric_limits<double>::infinity();

  for (int iteration = 0;; ++iteration) {
    objective.gradient(g);
    if (g.size() != n)
      throw Error("newtonSolve: Objective::gradient returned " + std::to_string(g.size()) +
                  " entries, expected numDofs() = " + std::to_string(n));
    objective.fixKinematic(g, nullptr);
    if (!g.allFinite()) {
      result.message = "the gradient is not finite; stopped at the last finite state";
      break;
    }
    const double gradient_norm = g.lpNorm<Eigen::Infinity>();
    result.gradient_norm = gradient_norm;
    if (iteration == 0) initial_gradient_norm = gradient_norm;
    if (gradient_norm <= options.gradient_tolerance * std::max(1.0, initial_gradient_norm)) {
      result.converged = true;
      result.message = format("gradient tolerance reached (|g|inf = %.3g)", gradient_norm);
      break;
    }
    if (iteration > 0 && last_step_norm <= options.step_tolerance) {
      result.converged = true;
      result.message = format("step tolerance reached (|step|inf = %.3g, |g|inf = %.3g)",
                              last_step_norm, gradient_norm);
      break;
    }
    if (iteration >= options.max_iterations) {
      result.message = format("max_iterations (%g) reached with |g|inf = %.3g",
                              options.max_iterations, gradient_norm);
      break;
    }

    // ---- Newton direction: H dq = −g. The exact Hessian first (quadratic convergence); if it
    // is not positive definite, the objective's PSD form; then diagonal shifts until it is.
    bool have_direction = false;
    double diagonal_scale = 1.0;
    for (int form = options.exact_hessian ? 0 : 1; form < 2 && !have_direction; ++form) {
      const bool psd = form == 1;
      if (psd && options.exact_hessian) ++result.psd_fallbacks;
      objective.hessian(H, psd);
      objective.fixKinematic(g, &H);
      if (H.rows() != n || H.cols() != n)
        throw Error("newtonSolve: Objective::hessian returned " +
                    shapeString({long(H.rows()), long(H.cols())}) + ", expected (" +
                    std::to_string(n) + ", " + std::to_string(n) + ")");
      diagonalPointers(H, diagonal);
      diagonal_scale = 0.0;
      for (int k = 0; k < n; ++k) diagonal_scale += std::abs(*diagonal[k]);
      diagonal_scale /= n;
      if (!(diagonal_scale > 0.0) || !std::isfinite(diagonal_scale)) diagonal_scale = 1.0;
      have_direction = solver->factorize(H);
    }
    if (!have_direction) {
      diagonal_values.resize(n);
      for (int k = 0; k < n; ++k) diagonal_values[k] = *diagonal[k];
      double shift = options.initial_regularization * diagonal_scale;
      for (int attempt = 0; attempt < kMaxRegularizationTries && !have_direction; ++attempt) {
        for (int k = 0; k < n; ++k) *diagonal[k] = diagonal_values[k] + shift;
        ++result.regularizations;
        have_direction = solver->factorize(H);
        shift *= 10.0;
      }
    }
    if (have_direction) {
      rhs = -g;
      dq = solver->solve(rhs);
      if (!dq.allFinite()) have_direction = false;
    }
    double slope = have_direction ? g.dot(dq) : 0.0;
    if (!have_direction || !(slope < 0.0)) {
      // No usable Newton direction (H singular beyond repair or not finite): scaled steepest
      // descent still decreases the energy and the line search keeps the state finite.
      dq = -g / diagonal_scale;
      slope = g.dot(dq);
    }

    // ---- Backtracking line search (Armijo); non-finite energies count as rejected.
    double alpha = 1.0;
    bool accepted = false;
    for (int trial = 0;; ++trial) {
      trial_step = alpha * dq;
      objective.push();
      objective.step(trial_step);
      const double trial_energy = objective.energy();
      if (std::isfinite(trial_energy) && trial_energy <= energy + options.armijo * alpha * slope +
                                                             kEnergyRoundOff * std::abs(energy)) {
        if (!objective.discardPushed()) {
          objective.pop();
          objective.step(trial_step);
        }
        energy = trial_energy;
        accepted = true;
        break;
      }
      objective.pop();
      if (trial >= options.max_line_search_steps) break;
      alpha *= 0.5;
      ++result.line_search_steps;
    }
    if (!accepted) {
      result.message =
          format("line search found no decrease after %g halvings (|g|inf = %.3g); state kept",
                 options.max_line_search_steps, gradient_norm);
      break;
    }
    last_step_norm = alpha * dq.lpNorm<Eigen::Infinity>();
    result.iterations = iteration + 1;
  }
  result.energy = energy;
  return result;
}

}  // namespace flsh
