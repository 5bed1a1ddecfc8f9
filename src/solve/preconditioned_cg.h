// Preconditioned conjugate gradients on a symmetric sparse (or dense-in-sparse) H with a
// Cholesky factor as the preconditioner and an optional coarse level (not public API): the
// lagged-factor directions of Newton (NewtonOptions::lagged) and the soft skeletons' adjoint
// solves (diff/tape.cpp: the exact Hessian of each step, preconditioned by a nearby step's
// factor).
#pragma once

#include "flsh/core/types.h"
#include "flsh/solve/linear_solver.h"
#include "solve/coarse_correction.h"

namespace flsh::detail {

enum class CgOutcome { Converged, NonPositiveCurvature, NotConverged, NotFinite };

/// Work vectors of PCG, kept across calls (each n).
struct CgWorkspace {
  VecX residual, preconditioned, direction, product;
};

/// Preconditioned conjugate gradients on H x = b from x = 0 with M⁻¹ = preconditioner's held
/// factor (`fast`: through preconditionInPlace, else the exact solveInPlace), with the coarse
/// level on top when `coarse` is active (built from this H); stops when
/// ‖b − H x‖₂ ≤ residual_tolerance. H is symmetric in full storage and need not be positive
/// definite: a direction with pᵀHp ≤ 0 stops it (NonPositiveCurvature). Every iterate is a
/// descent direction of ½xᵀHx − bᵀx as long as the curvatures met were positive.
CgOutcome preconditionedCg(const SpMat& H, const VecX& b, double residual_tolerance,
                           int max_iterations, const LinearSolver& preconditioner, bool fast,
                           const CoarseCorrection* coarse, VecX& x, CgWorkspace& w,
                           int& iterations);

}  // namespace flsh::detail
