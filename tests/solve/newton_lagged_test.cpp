// Newton with a lagged Cholesky factor and preconditioned CG (NewtonOptions::lagged) on a 3D
// nonlinear spring network of a few thousand DoFs, minimized over a sequence of related problems
// (like time steps) with one solver: it reaches the minimizers of plain Newton with fewer
// factorizations, survives indefinite exact Hessians, and its counters and timings add up.
// Also the LinearSolver calls PCG needs (hasFactor, factorRows, solveInPlace).
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "flsh/core/error.h"
#include "flsh/solve/linear_solver.h"
#include "flsh/solve/newton.h"
#include "solve/vector_state_objective.h"

namespace flsh {
namespace {

/// Nodes of an nx × ny × nz grid (spacing 1 m) joined by springs along the 7 edge directions of
/// the Kuhn tetrahedralization (14 neighbours per inner node, like a tet mesh), plus an inertia
/// term pulling every node to a target (x̂ of a backward-Euler step):
///   E(x) = w/2 ‖x − x̂‖² + Σ_springs k/2 (‖x_i − x_j‖ − L_ij)²,   x: #nodes × 3 stacked (m).
/// The exact spring Hessian k[nnᵀ + (1 − L/ℓ)(I − nnᵀ)] is indefinite for compressed springs;
/// the PSD form clamps 1 − L/ℓ at 0.
class SpringNetwork : public test::VectorStateObjective {
 public:
  SpringNetwork(int nx, int ny, int nz, double inertia_weight, double stiffness)
      : VectorStateObjective(VecX(), true), inertia_weight_(inertia_weight), stiffness_(stiffness) {
    const int nodes = nx * ny * nz;
    rest_.resize(3 * nodes);
    const auto id = [&](int i, int j, int k) { return (k * ny + j) * nx + i; };
    for (int k = 0; k < nz; ++k)
      for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) rest_.segment<3>(3 * id(i, j, k)) = Vec3(i, j, k);
    const int offsets[7][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 0},
                               {1, 0, 1}, {0, 1, 1}, {1, 1, 1}};
    for (int k = 0; k < nz; ++k)
      for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i)
          for (const auto& o : offsets)
            if (i + o[0] < nx && j + o[1] < ny && k + o[2] < nz) {
              const int a = id(i, j, k), b = id(i + o[0], j + o[1], k + o[2]);
              springs_.emplace_back(a, b);
              rest_length_.push_back((rest_.segment<3>(3 * a) - rest_.segment<3>(3 * b)).norm());
            }
    x = rest_;
    target = rest_;
  }

  /// Rest positions twisted by `angle` (rad) about the z axis through the grid's centre, in
  /// proportion to height, and scaled by `scale` about that centre (#nodes·3).
  VecX deformedRest(double angle, double scale) const {
    const Vec3 centre = Eigen::Map<const Eigen::Matrix<double, 3, Eigen::Dynamic>>(rest_.data(), 3,
                                                                                   rest_.size() / 3)
                            .rowwise()
                            .mean();
    const double height = std::max(1.0, 2.0 * centre.z());
    VecX out(rest_.size());
    for (Eigen::Index a = 0; a < rest_.size() / 3; ++a) {
      const Vec3 p = rest_.segment<3>(3 * a) - centre;
      const double t = angle * (p.z() + centre.z()) / height;
      const Vec3 q(std::cos(t) * p.x() - std::sin(t) * p.y(),
                   std::sin(t) * p.x() + std::cos(t) * p.y(), p.z());
      out.segment<3>(3 * a) = centre + scale * q;
    }
    return out;
  }

  int numDofs() const override { return int(x.size()); }

  double energy() override {
    double e = 0.5 * inertia_weight_ * (x - target).squaredNorm();
    for (size_t s = 0; s < springs_.size(); ++s) {
      const double stretch = edge(s).norm() - rest_length_[s];
      e += 0.5 * stiffness_ * stretch * stretch;
    }
    return e;
  }

  void gradient(VecX& g) override {
    g = inertia_weight_ * (x - target);
    for (size_t s = 0; s < springs_.size(); ++s) {
      const Vec3 d = edge(s);
      const double length = d.norm();
      const Vec3 force = stiffness_ * (length - rest_length_[s]) / length * d;
      g.segment<3>(3 * springs_[s].first) += force;
      g.segment<3>(3 * springs_[s].second) -= force;
    }
  }

  void hessian(SpMat& H, bool psd) override {
    ++(psd ? psd_hessians : exact_hessians);
    const int n = numDofs();
    std::vector<Triplet> entries;
    entries.reserve(size_t(n) + 36 * springs_.size());
    for (int k = 0; k < n; ++k) entries.emplace_back(k, k, inertia_weight_);
    for (size_t s = 0; s < springs_.size(); ++s) {
      const Vec3 d = edge(s);
      const double length = d.norm();
      const Vec3 unit = d / length;
      double transverse = 1.0 - rest_length_[s] / length;
      if (psd) transverse = std::max(transverse, 0.0);
      const Mat3 block = stiffness_ * (unit * unit.transpose() +
                                       transverse * (Mat3::Identity() - unit * unit.transpose()));
      const int a = 3 * springs_[s].first, b = 3 * springs_[s].second;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) {
          entries.emplace_back(a + r, a + c, block(r, c));
          entries.emplace_back(b + r, b + c, block(r, c));
          entries.emplace_back(a + r, b + c, -block(r, c));
          entries.emplace_back(b + r, a + c, -block(r, c));
        }
    }
    H.resize(n, n);
    H.setFromTriplets(entries.begin(), entries.end());
  }

  VecX target;  ///< x̂ (m), #nodes·3
  int exact_hessians = 0, psd_hessians = 0;

 private:
  Vec3 edge(size_t s) const {
    return x.segment<3>(3 * springs_[s].first) - x.segment<3>(3 * springs_[s].second);
  }

  double inertia_weight_, stiffness_;
  VecX rest_;
  std::vector<std::pair<int, int>> springs_;
  std::vector<double> rest_length_;
};

/// Sums of NewtonResult counters over a sequence of calls.
struct SequenceTotals {
  int iterations = 0, factorizations = 0, cg_iterations = 0, psd_fallbacks = 0;
  int calls_without_factorization = 0;
  double largest_gradient_ratio = 0.0;  ///< max over calls of ‖g_end‖∞ / max(1, ‖g₀‖∞)
  std::vector<VecX> minimizers;         ///< x after each call
};

/// Time-step-like sequence: call t moves the target to the rest shape twisted by t·0.1 rad
/// and minimizes from the previous minimizer, with one solver for all calls.
SequenceTotals runSequence(SpringNetwork& network, const NewtonOptions& options,
                           LinearSolver& solver, int calls) {
  SequenceTotals totals;
  for (int t = 1; t <= calls; ++t) {
    network.target = network.deformedRest(0.1 * t, 1.0);
    VecX g0;
    network.gradient(g0);
    const int solver_factorizations_before = solver.numFactorizations();
    const NewtonResult r = newtonSolve(network, options, &solver);
    EXPECT_TRUE(r.converged) << "call " << t << ": " << r.message;
    EXPECT_EQ(solver.numFactorizations() - solver_factorizations_before, r.factorizations)
        << "call " << t;
    totals.iterations += r.iterations;
    totals.factorizations += r.factorizations;
    totals.cg_iterations += r.cg_iterations;
    totals.psd_fallbacks += r.psd_fallbacks;
    if (r.factorizations == 0) ++totals.calls_without_factorization;
    totals.largest_gradient_ratio =
        std::max(totals.largest_gradient_ratio,
                 r.gradient_norm / std::max(1.0, g0.lpNorm<Eigen::Infinity>()));
    totals.minimizers.push_back(network.x);
  }
  return totals;
}

NewtonOptions laggedOptions() {
  NewtonOptions options;
  options.lagged.enabled = true;
  return options;
}

// 8 × 8 × 8 nodes: 1536 DoFs, 2 863 springs. Inertia weight m/h² = 0.05 N/m against spring
// stiffness 1 N/m: the springs dominate, so each call takes several Newton iterations.
constexpr int kGrid = 8;
constexpr double kInertiaWeight = 0.05, kStiffness = 1.0;
constexpr int kCalls = 10;

TEST(LaggedNewton, ReachesPlainNewtonsMinimizersWithFewerFactorizations) {
  NewtonOptions plain_options;
  plain_options.gradient_tolerance = 1e-9;
  NewtonOptions lagged_options = laggedOptions();
  lagged_options.gradient_tolerance = 1e-9;

  SpringNetwork plain_network(kGrid, kGrid, kGrid, kInertiaWeight, kStiffness);
  auto plain_solver = makeLinearSolver(LinearSolverType::Cholmod, plain_network.numDofs());
  const SequenceTotals plain = runSequence(plain_network, plain_options, *plain_solver, kCalls);

  SpringNetwork lagged_network(kGrid, kGrid, kGrid, kInertiaWeight, kStiffness);
  auto lagged_solver = makeLinearSolver(LinearSolverType::Cholmod, lagged_network.numDofs());
  const SequenceTotals lagged = runSequence(lagged_network, lagged_options, *lagged_solver, kCalls);

  // The problem is nonlinear enough to need several iterations per call.
  EXPECT_GT(plain.iterations, 2 * kCalls);
  EXPECT_EQ(plain.cg_iterations, 0);
  EXPECT_GE(plain.factorizations, plain.iterations);
  EXPECT_LE(plain.largest_gradient_ratio, 1e-9);
  EXPECT_LE(lagged.largest_gradient_ratio, 1e-9);

  // Same minimizers: both end with ‖g‖ ≤ 1e-9·‖g₀‖; the inertia term bounds H below by
  // 0.05 N/m, so the positions agree far below the 1e-6 m asserted here.
  ASSERT_EQ(plain.minimizers.size(), lagged.minimizers.size());
  for (size_t t = 0; t < plain.minimizers.size(); ++t) {
    EXPECT_GT((plain.minimizers[t] - plain_network.deformedRest(0.0, 1.0)).norm(), 0.1)
        << "call " << t + 1 << " did not move the network";
    EXPECT_LE((plain.minimizers[t] - lagged.minimizers[t]).lpNorm<Eigen::Infinity>(), 1e-6)
        << "call " << t + 1;
  }

  // The lag: fewer factorizations than Newton iterations, CG doing the rest, and whole calls
  // (time steps) preconditioned by an earlier call's factor.
  EXPECT_LT(lagged.factorizations, lagged.iterations);
  EXPECT_LT(lagged.factorizations, plain.factorizations);
  EXPECT_GT(lagged.cg_iterations, 0);
  EXPECT_GT(lagged.calls_without_factorization, 0);
}

// lagged.reuse_hessian_below: near convergence PCG runs on the previous iterate's Hessian (a
// chord step) instead of assembling one; the calls reach the same minimizers with fewer
// assemblies, never two reuses in a row.
TEST(LaggedNewton, ReusesThePreviousHessianNearConvergence) {
  NewtonOptions fresh_options = laggedOptions();
  fresh_options.gradient_tolerance = 1e-9;
  NewtonOptions reuse_options = fresh_options;
  reuse_options.lagged.reuse_hessian_below = 1e-5;

  SpringNetwork fresh_network(kGrid, kGrid, kGrid, kInertiaWeight, kStiffness);
  SpringNetwork reuse_network(kGrid, kGrid, kGrid, kInertiaWeight, kStiffness);
  auto fresh_solver = makeLinearSolver(LinearSolverType::Cholmod, fresh_network.numDofs());
  auto reuse_solver = makeLinearSolver(LinearSolverType::Cholmod, reuse_network.numDofs());
  int fresh_assemblies = 0, reuse_assemblies = 0, reuses = 0;
  for (int t = 1; t <= kCalls; ++t) {
    fresh_network.target = reuse_network.target = fresh_network.deformedRest(0.1 * t, 1.0);
    VecX g0;
    reuse_network.gradient(g0);
    const NewtonResult fresh = newtonSolve(fresh_network, fresh_options, fresh_solver.get());
    const NewtonResult reuse = newtonSolve(reuse_network, reuse_options, reuse_solver.get());
    ASSERT_TRUE(fresh.converged && reuse.converged) << fresh.message << " / " << reuse.message;
    EXPECT_EQ(fresh.hessian_reuses, 0);
    // Every iteration has a Hessian, assembled or reused; reuses never come twice in a row.
    EXPECT_GE(reuse.hessian_evaluations + reuse.hessian_reuses, reuse.iterations);
    EXPECT_LE(2 * reuse.hessian_reuses, reuse.iterations);
    EXPECT_LE(reuse.gradient_norm, 1e-9 * std::max(1.0, g0.lpNorm<Eigen::Infinity>()));
    EXPECT_LE((fresh_network.x - reuse_network.x).lpNorm<Eigen::Infinity>(), 1e-6) << "call " << t;
    fresh_assemblies += fresh.hessian_evaluations;
    reuse_assemblies += reuse.hessian_evaluations;
    reuses += reuse.hessian_reuses;
  }
  EXPECT_GT(reuses, 0);
  EXPECT_LT(reuse_assemblies, fresh_assemblies);
}

TEST(LaggedNewton, CountersAndTimingsAreConsistent) {
  SpringNetwork network(kGrid, kGrid, kGrid, kInertiaWeight, kStiffness);
  auto solver = makeLinearSolver(LinearSolverType::Cholmod, network.numDofs());
  const NewtonOptions options = laggedOptions();
  for (int t = 1; t <= 4; ++t) {
    network.target = network.deformedRest(0.1 * t, 1.0);
    const int exact_before = network.exact_hessians, psd_before = network.psd_hessians;
    const auto start = std::chrono::steady_clock::now();
    const NewtonResult r = newtonSolve(network, options, solver.get());
    const double elapsed =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    ASSERT_TRUE(r.converged) << r.message;
    for (const double seconds : {r.seconds_energy, r.seconds_gradient, r.seconds_hessian,
                                 r.seconds_factorization, r.seconds_solve})
      EXPECT_GE(seconds, 0.0);
    // Disjoint intervals inside the call.
    EXPECT_LE(r.seconds_energy + r.seconds_gradient + r.seconds_hessian + r.seconds_factorization +
                  r.seconds_solve,
              elapsed);
    EXPECT_GT(r.seconds_hessian, 0.0);
    EXPECT_GT(r.seconds_solve, 0.0);
    EXPECT_LE(r.factorizations, r.iterations);
    // PCG assembles the exact form, a refresh of the factor the PSD form (springs in tension:
    // PCG never meets negative curvature here, so the PSD form is assembled for refreshes only).
    const int exact = network.exact_hessians - exact_before;
    const int psd = network.psd_hessians - psd_before;
    EXPECT_EQ(exact + psd, r.hessian_evaluations);
    EXPECT_LE(exact, r.iterations);
    EXPECT_EQ(psd, r.factorizations);
    EXPECT_EQ(r.psd_fallbacks, r.factorizations);
    if (t == 1) {
      EXPECT_GE(r.factorizations, 1);  // no factor yet: the first direction factors
      EXPECT_GT(r.seconds_factorization, 0.0);
    }
    if (t > 1) {
      EXPECT_GT(r.cg_iterations, 0) << "call " << t;
    }
  }
}

TEST(LaggedNewton, FactorsThePsdFormWhenPcgDoesNotConverge) {
  // One PCG iteration with a lagged factor cannot reach a 1e-6 forcing term on this problem:
  // every PCG attempt (on the exact form) fails and that iteration factors the PSD form.
  SpringNetwork network(kGrid, kGrid, kGrid, kInertiaWeight, kStiffness);
  auto solver = makeLinearSolver(LinearSolverType::Cholmod, network.numDofs());
  NewtonOptions options = laggedOptions();
  options.lagged.max_cg_iterations = 1;
  options.lagged.cg_relative_tolerance = 1e-6;
  options.lagged.adaptive_forcing = false;
  options.lagged.refactor_after_cg_iterations = 1;  // a single iteration never marks it stale
  NewtonOptions plain_options;
  SpringNetwork plain_network(kGrid, kGrid, kGrid, kInertiaWeight, kStiffness);
  for (int t = 1; t <= 3; ++t) {
    network.target = network.deformedRest(0.1 * t, 1.0);
    plain_network.target = network.target;
    const int exact_before = network.exact_hessians, psd_before = network.psd_hessians;
    const NewtonResult r = newtonSolve(network, options, solver.get());
    ASSERT_TRUE(r.converged) << r.message;
    const NewtonResult plain = newtonSolve(plain_network, plain_options);
    ASSERT_TRUE(plain.converged) << plain.message;
    // PCG on the exact form wherever a factor is held (not before the first factorization).
    EXPECT_EQ(network.exact_hessians - exact_before, t == 1 ? r.iterations - 1 : r.iterations);
    EXPECT_EQ(network.psd_hessians - psd_before, r.iterations);
    // Each iteration: one PCG iteration, then one factorization (the first call has no factor).
    EXPECT_EQ(r.factorizations, r.iterations);
    EXPECT_EQ(r.cg_iterations, t == 1 ? r.iterations - 1 : r.iterations);
    EXPECT_LE((network.x - plain_network.x).lpNorm<Eigen::Infinity>(), 1e-5);
  }
}

TEST(LaggedNewton, PlainNewtonFactorsEveryIteration) {
  SpringNetwork network(kGrid, kGrid, kGrid, kInertiaWeight, kStiffness);
  network.target = network.deformedRest(0.1, 1.0);
  auto solver = makeLinearSolver(LinearSolverType::Cholmod, network.numDofs());
  const NewtonResult r = newtonSolve(network, NewtonOptions{}, solver.get());
  ASSERT_TRUE(r.converged) << r.message;
  EXPECT_GT(r.iterations, 1);
  EXPECT_EQ(r.factorizations, r.iterations + r.psd_fallbacks + r.regularizations);
  EXPECT_EQ(r.cg_iterations, 0);
  EXPECT_GT(r.seconds_factorization, 0.0);
}

TEST(LaggedNewton, ConvergesWhenTheExactHessianIsIndefinite) {
  // A weak inertia term pulling to a shape compressed to 60 %: every spring starts compressed,
  // so the exact Hessian (transverse stiffness 1 − L/ℓ = −2/3) is indefinite.
  SpringNetwork network(6, 6, 6, 1e-3, kStiffness);
  auto solver = makeLinearSolver(LinearSolverType::Cholmod, network.numDofs());
  const NewtonOptions options = laggedOptions();
  {
    SpMat H;
    network.x = network.deformedRest(0.0, 0.6);
    network.hessian(H, false);
    ASSERT_LT(Eigen::SelfAdjointEigenSolver<MatX>(MatX(H)).eigenvalues().minCoeff(), -0.1);
  }
  // The same calls with the PSD form only (exact_hessian = false), for comparison.
  SpringNetwork psd_network(6, 6, 6, 1e-3, kStiffness);
  auto psd_solver = makeLinearSolver(LinearSolverType::Cholmod, psd_network.numDofs());
  NewtonOptions psd_options = options;
  psd_options.exact_hessian = false;
  int exact_used = 0;  // iterations on the exact form, over the calls
  for (int t = 1; t <= 3; ++t) {
    // Each call restarts compressed and twisted, with the factor of the previous call held.
    // PCG on the exact Hessian meets negative curvature while the springs are compressed, and
    // that iteration falls back to the PSD form; the exact form is tried again at every
    // iteration, and once the springs near their rest lengths it is positive definite and used.
    network.x = network.deformedRest(0.2 * t, 0.6);
    network.target = network.x;
    psd_network.x = network.x;
    psd_network.target = network.target;
    VecX g0;
    network.gradient(g0);
    const int exact_before = network.exact_hessians;
    const NewtonResult r = newtonSolve(network, options, solver.get());
    ASSERT_TRUE(r.converged) << "call " << t << ": " << r.message;
    EXPECT_GE(network.exact_hessians - exact_before, 1) << "call " << t;
    EXPECT_LE(network.exact_hessians - exact_before, r.iterations) << "call " << t;
    EXPECT_GE(r.psd_fallbacks, 1) << "call " << t;  // the start is indefinite
    exact_used += r.iterations - r.psd_fallbacks;
    EXPECT_GE(r.factorizations, 1) << "call " << t;
    VecX g;
    network.gradient(g);
    EXPECT_LE(g.lpNorm<Eigen::Infinity>(),
              options.gradient_tolerance * std::max(1.0, g0.lpNorm<Eigen::Infinity>()));
    if (t > 1) {
      EXPECT_GT(r.cg_iterations, 0) << "call " << t;
    }
    // No more iterations than the PSD-only solve (whose linear convergence near a compressed
    // minimum is what trying the exact form each iteration avoids).
    const NewtonResult r_psd = newtonSolve(psd_network, psd_options, psd_solver.get());
    ASSERT_TRUE(r_psd.converged) << "call " << t << ": " << r_psd.message;
    EXPECT_LE(r.iterations, r_psd.iterations) << "call " << t;
    std::printf("call %d: %d iterations (%d on the PSD form), PSD form only: %d\n", t, r.iterations,
                r.psd_fallbacks, r_psd.iterations);
  }
  EXPECT_GT(exact_used, 0);  // the exact form came back once positive definite
}

TEST(LaggedNewton, RejectsInvalidLaggedOptionsNamingTheField) {
  SpringNetwork network(2, 2, 2, kInertiaWeight, kStiffness);
  const auto expectError = [&](const NewtonOptions& options, const std::string& field) {
    try {
      newtonSolve(network, options);
      ADD_FAILURE() << "no InputError for " << field;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
    }
  };
  NewtonOptions options = laggedOptions();
  options.lagged.max_cg_iterations = -1;
  expectError(options, "lagged.max_cg_iterations");
  options = laggedOptions();
  options.lagged.max_cg_iterations = 0;
  expectError(options, "lagged.max_cg_iterations");
  options = laggedOptions();
  options.lagged.refactor_after_cg_iterations = -3;
  expectError(options, "lagged.refactor_after_cg_iterations");
  for (const double bad : {0.0, -0.1, 1.0, std::nan("")}) {
    options = laggedOptions();
    options.lagged.cg_relative_tolerance = bad;
    expectError(options, "lagged.cg_relative_tolerance");
  }
  for (const double bad : {-1e-4, std::nan(""), std::numeric_limits<double>::infinity()}) {
    options = laggedOptions();
    options.lagged.reuse_hessian_below = bad;
    expectError(options, "lagged.reuse_hessian_below");
  }
  // Validated even while the lag is off, so that a bad configuration never waits to be used.
  options = NewtonOptions{};
  options.lagged.max_cg_iterations = -1;
  expectError(options, "lagged.max_cg_iterations");
}

class FactorStateTest : public ::testing::TestWithParam<LinearSolverType> {};

TEST_P(FactorStateTest, ReportsItsFactorAndSolvesInPlace) {
  SpringNetwork network(3, 3, 2, kInertiaWeight, kStiffness);
  network.x = network.deformedRest(0.3, 1.1);
  SpMat H;
  network.hessian(H, true);
  H.makeCompressed();
  const int n = int(H.rows());
  auto solver = makeLinearSolver(GetParam(), n);
  EXPECT_FALSE(solver->hasFactor());
  EXPECT_EQ(solver->factorRows(), 0);
  ASSERT_TRUE(solver->factorize(H));
  EXPECT_TRUE(solver->hasFactor());
  EXPECT_EQ(solver->factorRows(), n);

  std::mt19937 rng(7);
  std::normal_distribution<double> gauss(0.0, 1.0);
  VecX b(n);
  for (int k = 0; k < n; ++k) b[k] = gauss(rng);
  const VecX x = solver->solve(b);
  ASSERT_GT(x.norm(), 0.0);
  EXPECT_LE((H * x - b).norm(), 1e-10 * b.norm());
  VecX in_place = b;
  solver->solveInPlace(in_place);
  EXPECT_LE((in_place - x).lpNorm<Eigen::Infinity>(), 1e-12 * x.lpNorm<Eigen::Infinity>());
  VecX wrong_size(n + 1);
  wrong_size.setOnes();
  EXPECT_THROW(solver->solveInPlace(wrong_size), InputError);

  // A failed factorization drops the factor: PCG must not precondition with it.
  SpMat negative = -H;
  EXPECT_FALSE(solver->factorize(negative));
  EXPECT_FALSE(solver->hasFactor());
  EXPECT_EQ(solver->factorRows(), 0);
  VecX after_failure = b;
  EXPECT_THROW(solver->solveInPlace(after_failure), Error);
}

INSTANTIATE_TEST_SUITE_P(Backends, FactorStateTest,
                         ::testing::Values(LinearSolverType::Dense, LinearSolverType::Cholmod,
                                           LinearSolverType::SparseLLT));

}  // namespace
}  // namespace flsh
