// Internals shared by the linear-solver backends (not public API).
#pragma once

#include <memory>

#include "flsh/solve/linear_solver.h"

namespace flsh::detail {

/// CHOLMOD supernodal Cholesky (cholmod_solver.cpp).
std::unique_ptr<LinearSolver> makeCholmodSolver();

/// Throws InputError unless A is square; `who` names the caller in the message.
void checkSquare(const SpMat& A, const char* who);

/// True when every stored value of A is finite.
bool allFinite(const SpMat& A);

}  // namespace flsh::detail
