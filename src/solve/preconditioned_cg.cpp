#include "solve/preconditioned_cg.h"

#include <cmath>

namespace flsh::detail {

CgOutcome preconditionedCg(const SpMat& H, const VecX& b, double residual_tolerance,
                           int max_iterations, const LinearSolver& preconditioner, bool fast,
                           const CoarseCorrection* coarse, VecX& x, CgWorkspace& w,
                           int& iterations) {
  auto factorSolve = [&](VecX& v) {
    if (fast)
      preconditioner.preconditionInPlace(v);
    else
      preconditioner.solveInPlace(v);
  };
  auto precondition = [&](VecX& v) {
    if (coarse && coarse->active())
      coarse->apply(v, factorSolve);
    else
      factorSolve(v);
  };
  x.setZero(b.size());
  w.product.resize(b.size());
  w.residual = b;
  w.preconditioned = w.residual;
  precondition(w.preconditioned);
  w.direction = w.preconditioned;
  double rz = w.residual.dot(w.preconditioned);
  if (!std::isfinite(rz) || !(rz > 0.0)) return CgOutcome::NotFinite;
  // H in full n × n storage (HessianAssembler::setDense) is a column-major dense matrix.
  const Eigen::Index n = H.rows();
  const bool dense = H.isCompressed() && H.nonZeros() == n * n;
  const Eigen::Map<const MatX> H_dense(H.valuePtr(), dense ? n : 0, dense ? n : 0);
  for (int k = 0; k < max_iterations; ++k) {
    // H is symmetric: row c of H p is column c · p, so large products split over the columns
    // with no shared writes (27 k DoFs: ~1.3 → ~0.7 ms; a quarter of a PCG iteration since the
    // preconditioner runs in single precision on both cores). Eigen's own OpenMP product (of
    // a row-major Hᵀ) was 15× slower here: threads waiting at its barriers.
    if (dense) {
      // Column dot products too, split over the threads from a few hundred DoFs (ROM, 405:
      // ~25 → ~15 µs per product).
      const double* p = w.direction.data();
      double* out = w.product.data();
#pragma omp parallel for schedule(static) if (n >= 256)
      for (Eigen::Index c = 0; c < n; ++c)
        out[c] = H_dense.col(c).dot(Eigen::Map<const VecX>(p, n));
    } else if (!H.isCompressed()) {
      w.product.noalias() = H * w.direction;
    } else {
      const int* outer = H.outerIndexPtr();
      const int* inner = H.innerIndexPtr();
      const double* values = H.valuePtr();
      const double* p = w.direction.data();
      double* out = w.product.data();
#pragma omp parallel for schedule(static) if (n > 20000)
      for (Eigen::Index c = 0; c < n; ++c) {
        double sum = 0.0;
        for (int k = outer[c]; k < outer[c + 1]; ++k) sum += values[k] * p[inner[k]];
        out[c] = sum;
      }
    }
    ++iterations;
    const double curvature = w.direction.dot(w.product);
    if (!std::isfinite(curvature)) return CgOutcome::NotFinite;
    if (!(curvature > 0.0)) return CgOutcome::NonPositiveCurvature;
    const double alpha = rz / curvature;
    x.noalias() += alpha * w.direction;
    w.residual.noalias() -= alpha * w.product;
    const double residual_norm = w.residual.norm();
    if (!std::isfinite(residual_norm)) return CgOutcome::NotFinite;
    if (residual_norm <= residual_tolerance) return CgOutcome::Converged;
    w.preconditioned = w.residual;
    precondition(w.preconditioned);
    const double rz_next = w.residual.dot(w.preconditioned);
    if (!std::isfinite(rz_next) || !(rz_next > 0.0)) return CgOutcome::NotFinite;
    w.direction = w.preconditioned + (rz_next / rz) * w.direction;
    rz = rz_next;
  }
  return CgOutcome::NotConverged;
}

}  // namespace flsh::detail
