// Checks of Ceres cost functions' Jacobians shared by the tests of tests/ceres: every analytic
// block nonzero, then against central differences of the whole block and against Ceres'
// GradientChecker (entry-wise).
#pragma once

#include <ceres/cost_function.h>
#include <ceres/dynamic_numeric_diff_cost_function.h>
#include <ceres/gradient_checker.h>
#include <ceres/manifold.h>
#include <ceres/problem.h>
#include <ceres/solver.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "support/test_support.h"

namespace flsh::test {

// All Jacobian blocks of one evaluation (row-major, as Ceres fills them).
inline std::vector<RowMatX> jacobiansOf(const ceres::CostFunction& cost,
                                        const std::vector<const double*>& parameters) {
  std::vector<RowMatX> blocks;
  std::vector<double*> pointers;
  for (int32_t size : cost.parameter_block_sizes()) blocks.emplace_back(cost.num_residuals(), size);
  for (RowMatX& b : blocks) pointers.push_back(b.data());
  VecX r(cost.num_residuals());
  EXPECT_TRUE(cost.Evaluate(parameters.data(), r.data(), pointers.data()));
  return blocks;
}

/// Pointers to each vector's values: a cost's parameter blocks.
inline std::vector<const double*> pointersTo(const std::vector<VecX>& values) {
  std::vector<const double*> p;
  for (const VecX& v : values) p.push_back(v.data());
  return p;
}

/// Two costs' Jacobian blocks at the same parameters agree: every block of `a` nonzero and
/// max |a − b| ≤ tolerance · max |a| per block (e.g. forward sensitivities against the adjoint).
inline ::testing::AssertionResult sameJacobians(const ceres::CostFunction& a,
                                                const ceres::CostFunction& b,
                                                const std::vector<const double*>& parameters,
                                                double tolerance) {
  const std::vector<RowMatX> ja = jacobiansOf(a, parameters), jb = jacobiansOf(b, parameters);
  for (size_t k = 0; k < ja.size(); ++k) {
    const double scale = ja[k].cwiseAbs().maxCoeff();
    if (scale < 1e-8) return ::testing::AssertionFailure() << "block " << k << " is zero";
    const double off = (ja[k] - jb[k]).cwiseAbs().maxCoeff();
    if (off > tolerance * scale)
      return ::testing::AssertionFailure()
             << "block " << k << ": max difference " << off << " against " << scale;
  }
  return ::testing::AssertionSuccess();
}

/// Levenberg–Marquardt with dense QR, one thread, to tight tolerances (function and gradient:
/// `tolerance`; parameters 1e-12): for solves that must reach synthetic ground truth.
inline ceres::Solver::Summary solveTightly(ceres::Problem& problem, int max_iterations = 30,
                                           double tolerance = 1e-16) {
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::DENSE_QR;
  options.max_num_iterations = max_iterations;
  options.function_tolerance = tolerance;
  options.gradient_tolerance = tolerance;
  options.parameter_tolerance = 1e-12;
  options.num_threads = 1;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  return summary;
}

// Every analytic block is nonzero and matches central differences of re-run rollouts as a
// whole: max |analytic − numeric| ≤ tolerance · max |numeric| (the sharp check of the chain).
inline ::testing::AssertionResult matchesCentralDifferences(
    const ceres::CostFunction& cost, const std::vector<const double*>& parameters,
    double tolerance = 1e-6) {
  const std::vector<RowMatX> analytic = jacobiansOf(cost, parameters);
  const std::vector<int32_t>& sizes = cost.parameter_block_sizes();
  for (size_t b = 0; b < analytic.size(); ++b) {
    if (analytic[b].cwiseAbs().maxCoeff() < 1e-8)
      return ::testing::AssertionFailure() << "analytic Jacobian block " << b << " is zero";
    const auto f = [&](const VecX& x) {
      std::vector<const double*> moved = parameters;
      moved[b] = x.data();
      VecX r(cost.num_residuals());
      cost.Evaluate(moved.data(), r.data(), nullptr);
      return r;
    };
    const ::testing::AssertionResult whole = jacobianMatchesFiniteDifferences(
        f, Eigen::Map<const VecX>(parameters[b], sizes[b]), MatX(analytic[b]), tolerance);
    if (!whole) return ::testing::AssertionFailure() << "block " << b << ": " << whole.message();
  }
  return ::testing::AssertionSuccess();
}

// Ceres' GradientChecker (entry-wise |analytic − numeric| ≤ relative_precision · max(|·|), Ridders
// differences), after asserting that every analytic block is nonzero. Dynamics couple every
// input to every point, so a block's entries span many orders of magnitude (a hand's rotational
// velocity moves the pelvis by 1e-14 m per rad/s within a few steps); central differences of
// residuals of ~1 m carry ~1e-16/h round-off, so the smallest entries are only good to a few
// per cent and the precision is chosen per block kind. Probe gets no ProbeResults: its Eigen
// members would be allocated inside libceres (built without -march=native) and freed here with
// another alignment scheme (see smpl_costs_test.cpp).
inline ::testing::AssertionResult passesGradientChecker(
    const ceres::CostFunction& cost, const std::vector<const double*>& parameters,
    double relative_precision, const ceres::NumericDiffOptions& options = {}) {
  const std::vector<RowMatX> analytic = jacobiansOf(cost, parameters);
  const std::vector<int32_t>& sizes = cost.parameter_block_sizes();
  for (size_t b = 0; b < analytic.size(); ++b)
    if (analytic[b].cwiseAbs().maxCoeff() < 1e-8)
      return ::testing::AssertionFailure() << "analytic Jacobian block " << b << " is zero";
  const ceres::GradientChecker checker(
      &cost, static_cast<const std::vector<const ceres::Manifold*>*>(nullptr), options);
  if (checker.Probe(parameters.data(), relative_precision, nullptr))
    return ::testing::AssertionSuccess();
  // Say which entries fail Ceres' criterion, from a Ridders Jacobian of the same options (its
  // buffers are ours).
  auto failure = ::testing::AssertionFailure() << "GradientChecker rejected the Jacobians;";
  ceres::DynamicNumericDiffCostFunction<ceres::CostFunction, ceres::RIDDERS> numeric(
      &cost, ceres::DO_NOT_TAKE_OWNERSHIP, options);
  for (int32_t size : sizes) numeric.AddParameterBlock(size);
  numeric.SetNumResiduals(cost.num_residuals());
  std::vector<RowMatX> numeric_blocks;
  std::vector<double*> pointers;
  for (int32_t size : sizes) numeric_blocks.emplace_back(cost.num_residuals(), size);
  for (RowMatX& block : numeric_blocks) pointers.push_back(block.data());
  VecX r(cost.num_residuals());
  numeric.Evaluate(parameters.data(), r.data(), pointers.data());
  for (size_t b = 0; b < sizes.size(); ++b) {
    int bad = 0;
    for (int i = 0; i < cost.num_residuals(); ++i)
      for (int j = 0; j < sizes[b]; ++j) {
        const double a = analytic[b](i, j), n = numeric_blocks[b](i, j);
        if (std::abs(a - n) > relative_precision * std::max(std::abs(a), std::abs(n)) && bad++ < 4)
          failure << " block " << b << " (" << i << ", " << j << "): analytic " << a << ", numeric "
                  << n << ";";
      }
    failure << " block " << b << ": " << bad << " entries off;";
  }
  return failure;
}

// Ridders' extrapolation from a step of 1e-4 relative: Ceres' default 1e-2 crosses contact
// events (a vertex meeting the ground), where the rollout is only C¹, and was off by up to 10 %.
inline ceres::NumericDiffOptions contactDiffOptions() {
  ceres::NumericDiffOptions options;
  options.ridders_relative_initial_step_size = 1e-4;
  options.max_num_ridders_extrapolations = 2;
  return options;
}

}  // namespace flsh::test
