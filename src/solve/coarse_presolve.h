// Newton's coarse presolve (NewtonOptions::coarse_presolve): Newton iterations on an objective's
// coarse DoFs alone (Objective::coarseEnergyAndGradient / coarseHessian; a scene's: its avatars'
// bones with the soft tissue held) before the iterations on every DoF. Private to newtonSolve.
#pragma once

#include "flsh/solve/newton.h"

namespace flsh::detail {

/// Runs the presolve from the objective's current state (which it leaves at the presolve's
/// last accepted iterate) with `options`' line search and Hessian forms, a sparse Cholesky of
/// the coarse block's nonzero 6 × 6 blocks (Objective::coarseSolver, which keeps its analysis
/// between calls, or one of its own) and options.coarse_presolve's iteration limit and
/// tolerance. Adds its iterations to result.coarse_iterations and its time to result's
/// seconds. Returns ‖g_c‖∞ at the start (0 when nothing ran: no limit, no coarse DoFs or no
/// coarse form).
double coarsePresolve(Objective& objective, const NewtonOptions& options, NewtonResult& result);

}  // namespace flsh::detail
