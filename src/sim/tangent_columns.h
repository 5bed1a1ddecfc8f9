// A dense Jacobian from the map that adds its tangents, one column per unit direction: the soft
// skeletons' previous-state Jacobians, which the adjoint needs only as products (the dense form
// is for small models and tests). Private to Simulable.
#pragma once

#include "flsh/core/types.h"

namespace flsh::detail {

/// D.col(k) += tangent(e_k) for every column k; tangent(direction, out) ADDS into out (D.rows()).
template <class Tangent>
void addTangentColumns(MatX& D, Tangent&& tangent) {
  VecX unit = VecX::Zero(D.cols()), column(D.rows());
  for (Eigen::Index k = 0; k < D.cols(); ++k) {
    unit[k] = 1.0;
    column.setZero();
    tangent(unit, column);
    D.col(k) += column;
    unit[k] = 0.0;
  }
}

}  // namespace flsh::detail
