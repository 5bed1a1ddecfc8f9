// A sparse symmetric positive definite factor (CHOLMOD, supernodal) for the volume area's
// precomputations: the harmonic extension of the body's fields and the soft tissue's rest
// stiffness (modal_basis). Private to src/volume; the solve area has its own solver interface
// for Newton, which this area sits below.
#pragma once

#include <memory>
#include <string>

#include "flsh/core/types.h"

namespace flsh::detail {

class SparseCholesky {
 public:
  /// Factors A (symmetric, both triangles or the lower one; only the lower is read). `who`
  /// names the caller in errors. Throws Error when CHOLMOD fails or A is not positive definite
  /// (the message says at which column).
  SparseCholesky(const SpMat& A, const std::string& who);
  ~SparseCholesky();
  SparseCholesky(const SparseCholesky&) = delete;
  SparseCholesky& operator=(const SparseCholesky&) = delete;

  int rows() const { return rows_; }
  /// X = A⁻¹ B (rows() × k), in blocks of columns; thread-safe (one solve at a time).
  MatX solve(const MatX& B) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int rows_ = 0;
  std::string who_;
};

}  // namespace flsh::detail
