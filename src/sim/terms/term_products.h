// Internal helpers of the energy terms' parameter products (energy_term.h): the cotangent
// blocks of one bone, for a vector λ (numDofs) or a matrix Λ (numDofs × m) alike, so that each
// product is one template instantiated for both.
#pragma once

#include <Eigen/Core>

#include "flsh/core/types.h"
#include "flsh/sim/energy_term.h"

namespace flsh::detail {

/// Translation (rows 6b … 6b + 2) and rotation (6b + 3 …) cotangents of bone b: 3 × m.
template <class Lambda>
auto lambdaT(const Lambda& l, int b) {
  return l.template middleRows<3>(6 * b);
}
template <class Lambda>
auto lambdaW(const Lambda& l, int b) {
  return l.template middleRows<3>(6 * b + 3);
}

/// 1 × m and 3 × m blocks of the cotangent's width (fixed-size for a vector).
template <class Lambda>
using RowOf = Eigen::Matrix<double, 1, Lambda::ColsAtCompileTime>;
template <class Lambda>
using Rows3Of = Eigen::Matrix<double, 3, Lambda::ColsAtCompileTime>;

/// Subtree of every bone (itself included, ascending), from the parent list (root −1).
std::vector<std::vector<int>> boneSubtrees(const std::vector<int>& parents);

double totalMass(const std::vector<BoneInertia>& inertia);

}  // namespace flsh::detail
