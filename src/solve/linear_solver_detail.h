// Internals shared by the linear-solver backends (not public API).
#pragma once

#include <memory>

#include "flsh/solve/linear_solver.h"

namespace flsh::detail {

/// CHOLMOD supernodal Cholesky (cholmod_solver.cpp).
std::unique_ptr<LinearSolver> makeCholmodSolver();

/// For tests and benchmarks: the threads and the serial share of the factor (see
/// SupernodalPreconditioner) of the single-precision preconditioner a CHOLMOD solver built for
/// its current factor; {0, 1} for another solver or before the first preconditionInPlace().
struct PreconditionerSplit {
  int threads = 0;
  double serial_share = 1.0;
};
PreconditionerSplit preconditionerSplit(const LinearSolver& solver);

/// Throws InputError unless A is square; `who` names the caller in the message.
void checkSquare(const SpMat& A, const char* who);

/// True when every stored value of A is finite.
bool allFinite(const SpMat& A);

}  // namespace flsh::detail
