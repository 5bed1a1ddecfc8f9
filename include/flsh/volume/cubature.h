// Cubature for the ROM soft skeleton (ARCHITECTURE.md §4): a sum over all tets, Σ_e f_e, is
// replaced by a weighted sum over a few sample tets, Σ_{e∈S} w_e f_e with w ≥ 0, fitted on
// training data — Optimized Cubature (An, Kim & James 2008): greedy selection of the element
// most correlated with the residual, non-negative least squares (Lawson & Hanson) on the selected
// set, repeat. The training data need no simulation: e.g. element energies of random subspace
// deformations.
#pragma once

#include "flsh/core/types.h"

namespace flsh {

struct CubatureOptions {
  /// Largest number of selected elements (all with weight > 0). Must be ≥ 1.
  int count = 500;
  /// Stop early once the relative training error ‖A_S w − b‖ / ‖b‖ is at most this (≥ 0; 0:
  /// run until `count` elements or no element can lower the error).
  double tolerance = 0;
  /// Elements added per greedy round (the best-correlated ones): 1 follows the paper exactly;
  /// more cut the rounds, each of which correlates every element with the residual (one
  /// #samples × #elements product). Measured for 1000 samples × 39 000 tets, 500 elements: 1 →
  /// 10.4 s, 10 → 2.7 s (one core), with the same held-out error.
  int points_per_round = 10;
};

struct Cubature {
  VecXi elements;             ///< selected element indices (columns of A), ascending
  VecX weights;               ///< their weights, > 0 (dimensionless: 1 = the element itself)
  double training_error = 0;  ///< ‖A_S w − b‖ / ‖b‖ on the training matrix
  int rounds = 0;             ///< greedy rounds run
};

/// Selects at most options.count elements and non-negative weights that reproduce b = A·1 (exact
/// integration of every training sample). A: #samples × #elements, entry (s, e) = the quantity
/// (energy, force component) of element e in sample s. Deterministic (ties go to the lower
/// index). Stops early when a round no longer lowers the error (the residual is rounding noise).
/// Throws InputError if A is empty or has non-finite entries, if b = 0, or for options
/// out of range.
Cubature selectCubature(const MatX& A, const CubatureOptions& options = {});

/// Exact integration as a cubature: every one of `elements` elements with weight 1.
Cubature exactCubature(int elements);

/// Relative error ‖A_S w − A·1‖ / ‖A·1‖ of a cubature on a (held-out) matrix A (#samples ×
/// #elements). Throws InputError if A is empty or non-finite, A·1 = 0, elements and weights differ
/// in length, or an element index is outside [0, #elements).
double cubatureRelativeError(const MatX& A, const VecXi& elements, const VecX& weights);

/// argmin ‖A x − b‖ subject to x ≥ 0 (Lawson–Hanson active set; A: m × n, b: m). Solved on the
/// normal equations AᵀA, so the accuracy is that of cond(A)²·ε. At the result: x ≥ 0, the
/// gradient Aᵀ(Ax − b) is ≈ 0 where x > 0 and ≥ −tolerance where x = 0. Throws InputError on
/// mismatched sizes or non-finite entries.
VecX nonNegativeLeastSquares(const MatX& A, const VecX& b);

}  // namespace flsh
