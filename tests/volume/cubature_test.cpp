// Optimized cubature and Lawson–Hanson NNLS (cubature.h).
#include "flsh/volume/cubature.h"

#include <gtest/gtest.h>
#include <omp.h>

#include <Eigen/QR>
#include <limits>

#include "flsh/core/error.h"
#include "support/test_support.h"

namespace flsh {
namespace {

/// Training matrix of a synthetic "energy" problem: element e contributes
/// Σ_k c_ek · (mode k of sample s)², a few smooth modes shared by all elements, like element
/// energies of random subspace deformations (samples × elements, entries ≥ 0). The element
/// coefficients come from `seed`, the sample amplitudes from `amplitude_seed`.
MatX syntheticTraining(int samples, int elements, unsigned seed, unsigned amplitude_seed = 0) {
  const int modes = 6;
  const MatX coefficients = (test::randomVector(elements * modes, 1.0, seed).array() + 1.5)
                                .matrix()
                                .reshaped(elements, modes);
  const MatX amplitudes =
      test::randomVector(samples * modes, 1.0, amplitude_seed ? amplitude_seed : seed + 100)
          .reshaped(samples, modes);
  MatX A(samples, elements);
  for (int s = 0; s < samples; ++s)
    for (int e = 0; e < elements; ++e) {
      const double position = double(e) / elements;
      double value = 0;
      for (int k = 0; k < modes; ++k) {
        const double shape = std::cos(3.0 * k * position) * amplitudes(s, k);
        value += coefficients(e, k) * shape * shape;
      }
      A(s, e) = value;
    }
  return A;
}

TEST(Cubature, AllElementsWithUnitWeightsAreExact) {
  const MatX A = syntheticTraining(30, 50, 1);
  VecXi all(50);
  for (int e = 0; e < 50; ++e) all[e] = e;
  EXPECT_EQ(cubatureRelativeError(A, all, VecX::Ones(50)), 0.0);
  // Not trivially zero: dropping one element or scaling one weight makes an error.
  EXPECT_GT(cubatureRelativeError(A, all.head(49), VecX::Ones(49)), 1e-3);
  VecX scaled = VecX::Ones(50);
  scaled[7] = 1.5;
  EXPECT_GT(cubatureRelativeError(A, all, scaled), 1e-4);
}

TEST(Cubature, SelectionWithEnoughElementsReachesExactIntegration) {
  const MatX A = syntheticTraining(12, 40, 2);
  CubatureOptions options;
  options.count = 40;
  const Cubature cubature = selectCubature(A, options);
  // 12 samples: a non-negative fit with at most 12 elements exists (Carathéodory); the greedy
  // selection finds an exact one to rounding.
  EXPECT_LE(cubature.training_error, 1e-9);
  EXPECT_LE(cubature.elements.size(), 40);
  EXPECT_NEAR(cubatureRelativeError(A, cubature.elements, cubature.weights),
              cubature.training_error, 1e-12);
}

// The correlation of every element with the residual runs on the threads in fixed blocks of
// columns: the selection is the same, bit for bit, on one thread and on several (a matrix wider
// than one block).
TEST(Cubature, SelectionIsTheSameOnAnyNumberOfThreads) {
  const MatX A = syntheticTraining(20, 2500, 5);
  CubatureOptions options;
  options.count = 60;
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  const Cubature one = selectCubature(A, options);
  omp_set_num_threads(3);
  const Cubature three = selectCubature(A, options);
  omp_set_num_threads(threads);
  ASSERT_GE(one.elements.size(), 5);
  EXPECT_EQ(one.elements, three.elements);
  EXPECT_EQ(one.weights, three.weights);
  EXPECT_EQ(one.training_error, three.training_error);
  EXPECT_EQ(one.rounds, three.rounds);
}

TEST(Cubature, ErrorNeverIncreasesWithCountAndGeneralizes) {
  const MatX train = syntheticTraining(80, 300, 3);
  const MatX held_out = syntheticTraining(40, 300, 3, 777);  // same elements, other samples
  double previous = std::numeric_limits<double>::infinity();
  double first = 0;
  for (int count : {1, 2, 4, 8, 16, 32}) {
    CubatureOptions options;
    options.count = count;
    options.points_per_round = 1;  // nested selections: each count continues the previous run
    const Cubature cubature = selectCubature(train, options);
    ASSERT_LE(cubature.elements.size(), count);
    ASSERT_GE(cubature.elements.size(), 1);
    EXPECT_GT(cubature.weights.minCoeff(), 0);
    for (int k = 1; k < cubature.elements.size(); ++k)
      EXPECT_LT(cubature.elements[k - 1], cubature.elements[k]);  // ascending, distinct
    EXPECT_LE(cubature.training_error, previous + 1e-15) << count << " elements";
    if (count == 1) first = cubature.training_error;
    previous = cubature.training_error;
    const double test_error = cubatureRelativeError(held_out, cubature.elements, cubature.weights);
    if (count == 32) {
      EXPECT_LT(test_error, 0.05);
    }
  }
  EXPECT_LT(previous, 0.1 * first);  // the error really falls
}

TEST(Cubature, ToleranceStopsEarlyAndSelectionIsDeterministic) {
  const MatX A = syntheticTraining(60, 200, 4);
  CubatureOptions options;
  options.count = 100;
  options.tolerance = 1e-2;
  options.points_per_round = 1;
  const Cubature a = selectCubature(A, options);
  const Cubature b = selectCubature(A, options);
  EXPECT_LE(a.training_error, 1e-2);
  EXPECT_LT(a.elements.size(), 100);
  EXPECT_EQ(a.elements, b.elements);
  EXPECT_EQ(a.weights, b.weights);
  options.points_per_round = 4;
  const Cubature batched = selectCubature(A, options);
  EXPECT_LE(batched.training_error, 1e-2);
  EXPECT_LE(batched.rounds, a.rounds);
}

/// Brute force: the best least-squares fit over every support whose unconstrained solution is
/// non-negative.
VecX bruteForceNnls(const MatX& A, const VecX& b) {
  const int n = int(A.cols());
  VecX best = VecX::Zero(n);
  double best_residual = b.norm();
  for (int mask = 1; mask < (1 << n); ++mask) {
    std::vector<int> support;
    for (int i = 0; i < n; ++i)
      if (mask & (1 << i)) support.push_back(i);
    MatX As(A.rows(), support.size());
    for (int k = 0; k < int(support.size()); ++k) As.col(k) = A.col(support[k]);
    const VecX y = As.colPivHouseholderQr().solve(b);
    if (y.minCoeff() < 0) continue;
    const double residual = (As * y - b).norm();
    if (residual < best_residual) {
      best_residual = residual;
      best.setZero();
      for (int k = 0; k < int(support.size()); ++k) best[support[k]] = y[k];
    }
  }
  return best;
}

TEST(NonNegativeLeastSquares, MatchesBruteForceAndKkt) {
  int active_somewhere = 0;
  for (unsigned seed = 1; seed <= 20; ++seed) {
    const int m = 9, n = 6;
    const MatX A = test::randomVector(m * n, 1.0, seed).reshaped(m, n);
    const VecX b = test::randomVector(m, 1.0, seed + 1000);
    const VecX x = nonNegativeLeastSquares(A, b);
    const VecX reference = bruteForceNnls(A, b);
    EXPECT_LE((x - reference).cwiseAbs().maxCoeff(), 1e-9) << "seed " << seed;
    // KKT: x ≥ 0, gradient ≥ 0 where x = 0 and = 0 where x > 0.
    const VecX gradient = A.transpose() * (A * x - b);
    ASSERT_GE(x.minCoeff(), 0.0);
    for (int i = 0; i < n; ++i) {
      if (x[i] > 0) {
        EXPECT_NEAR(gradient[i], 0, 1e-10) << "seed " << seed << " entry " << i;
      } else {
        EXPECT_GE(gradient[i], -1e-10) << "seed " << seed << " entry " << i;
        if (gradient[i] > 1e-6) ++active_somewhere;
      }
    }
  }
  EXPECT_GT(active_somewhere, 5);  // the bounds are exercised, not just unconstrained fits
}

// Large enough that Lawson–Hanson's passive set grows by dozens of single entries (each a
// row appended to the kept Cholesky factor) with blocking steps between them (refactorizations):
// the solution must still satisfy the optimality conditions to rounding.
TEST(NonNegativeLeastSquares, ManyEntriesAndBlockingStepsKeepKkt) {
  int passive_total = 0, active_total = 0;
  for (unsigned seed = 1; seed <= 6; ++seed) {
    const int m = 150, n = 100;
    const MatX A = test::randomVector(m * n, 1.0, seed).reshaped(m, n);
    const VecX b = test::randomVector(m, 1.0, seed + 1000);
    const VecX x = nonNegativeLeastSquares(A, b);
    const VecX gradient = A.transpose() * (A * x - b);
    const double scale = (A.transpose() * b).cwiseAbs().maxCoeff();
    ASSERT_GT(scale, 0.0);
    ASSERT_GE(x.minCoeff(), 0.0);
    for (int i = 0; i < n; ++i) {
      if (x[i] > 0) {
        ++passive_total;
        EXPECT_NEAR(gradient[i], 0, 1e-11 * scale) << "seed " << seed << " entry " << i;
      } else {
        ++active_total;
        EXPECT_GE(gradient[i], -1e-11 * scale) << "seed " << seed << " entry " << i;
      }
    }
  }
  EXPECT_GT(passive_total, 6 * 20);  // dozens of entries per solve
  EXPECT_GT(active_total, 6 * 20);   // and many bounds active
}

// The selection's weights are the non-negative least-squares fit on the elements it kept
// (every weight > 0, so the fit's gradient vanishes there), over many rounds of warm starts.
TEST(Cubature, SelectedWeightsAreTheOptimalFitOnTheirElements) {
  // Generic non-negative entries (full rank, unlike syntheticTraining's few modes), so that the
  // selection runs to its count.
  const MatX A = test::randomVector(300 * 400, 1.0, 11).cwiseAbs().reshaped(300, 400);
  CubatureOptions options;
  options.count = 120;
  options.points_per_round = 3;
  const Cubature cubature = selectCubature(A, options);
  ASSERT_GT(cubature.elements.size(), 20);
  ASSERT_GT(cubature.rounds, 10);
  MatX As(A.rows(), cubature.elements.size());
  for (int k = 0; k < cubature.elements.size(); ++k) As.col(k) = A.col(cubature.elements[k]);
  const VecX b = A.rowwise().sum();
  const VecX gradient = As.transpose() * (As * cubature.weights - b);
  const double scale = (As.transpose() * b).cwiseAbs().maxCoeff();
  ASSERT_GT(scale, 0.0);
  EXPECT_GT(cubature.weights.minCoeff(), 0.0);
  EXPECT_LE(gradient.cwiseAbs().maxCoeff(), 1e-9 * scale);
}

TEST(NonNegativeLeastSquares, RepeatedAndZeroColumnsAreHandled) {
  MatX A(4, 3);
  A << 1, 1, 0,  //
      2, 2, 0,   //
      0, 0, 0,   //
      1, 1, 0;
  const VecX b = (VecX(4) << 2, 4, 1, 2).finished();
  const VecX x = nonNegativeLeastSquares(A, b);
  EXPECT_GE(x.minCoeff(), 0.0);
  EXPECT_NEAR(x[0] + x[1], 2.0, 1e-12);
  EXPECT_EQ(x[2], 0.0);
}

TEST(Cubature, RejectsBadInput) {
  const MatX A = syntheticTraining(5, 8, 5);
  EXPECT_NE(test::messageOf<InputError>([&] { selectCubature(MatX(0, 3)); }).find("(0, 3)"),
            std::string::npos);
  MatX nan = A;
  nan(1, 2) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(test::messageOf<InputError>([&] { selectCubature(nan); }).find("NaN"),
            std::string::npos);
  EXPECT_NE(test::messageOf<InputError>([&] {
              selectCubature(MatX::Zero(3, 4));
            }).find("target A·1 is zero"),
            std::string::npos);
  CubatureOptions bad;
  bad.count = 0;
  EXPECT_NE(test::messageOf<InputError>([&] { selectCubature(A, bad); }).find("count = 0"),
            std::string::npos);
  EXPECT_NE(test::messageOf<InputError>([&] {
              cubatureRelativeError(A, (VecXi(2) << 0, 8).finished(), VecX::Ones(2));
            }).find("elements[1] = 8"),
            std::string::npos);
  EXPECT_NE(test::messageOf<InputError>([&] {
              cubatureRelativeError(A, (VecXi(2) << 0, 1).finished(), VecX::Ones(3));
            }).find("2 elements but 3 weights"),
            std::string::npos);
  EXPECT_NE(test::messageOf<InputError>([&] {
              nonNegativeLeastSquares(A, VecX::Ones(4));
            }).find("b has 4 entries, expected 5"),
            std::string::npos);
}

}  // namespace
}  // namespace flsh
