#include "solve/coarse_presolve.h"

#include <algorithm>
#include <string>
#include <vector>

#include "flsh/core/error.h"

namespace flsh::detail {

namespace {

/// The objective seen on its coarse DoFs: steps are zero on every other DoF.
class CoarseView final : public Objective {
 public:
  /// `energy`, `g`: the coarse energy and gradient at the current state, which the first
  /// evaluation returns without asking again.
  CoarseView(Objective& whole, std::vector<int> dofs, double energy, VecX g)
      : whole_(whole), dofs_(std::move(dofs)), held_energy_(energy), held_gradient_(std::move(g)) {}
  int numDofs() const override { return int(dofs_.size()); }
  double energy() override {
    double E = 0.0;
    energyAndGradient(E, scratch_);
    return E;
  }
  void gradient(VecX& g) override {
    double E = 0.0;
    energyAndGradient(E, g);
  }
  bool energyAndGradient(double& energy, VecX& g) override {
    if (held_) {
      held_ = false;
      energy = held_energy_;
      g = held_gradient_;
      return true;
    }
    if (!whole_.coarseEnergyAndGradient(energy, g) || g.size() != numDofs())
      throw Error("newtonSolve: Objective::coarseEnergyAndGradient stopped answering or gave " +
                  std::to_string(g.size()) + " entries, expected " + std::to_string(numDofs()));
    return true;
  }
  void hessian(SpMat& H, bool psd) override {
    whole_.coarseHessian(dense_, psd);
    if (dense_.rows() != numDofs() || dense_.cols() != numDofs())
      throw Error("newtonSolve: Objective::coarseHessian gave " + std::to_string(dense_.rows()) +
                  " × " + std::to_string(dense_.cols()) + ", expected " +
                  std::to_string(numDofs()) + " square");
    blockSparse(H);
  }
  void step(const VecX& dq) override {
    held_ = false;
    step_.setZero(whole_.numDofs());
    for (size_t k = 0; k < dofs_.size(); ++k) step_[dofs_[k]] = dq[Eigen::Index(k)];
    whole_.step(step_);
  }
  void push() override { whole_.push(); }
  void pop() override { whole_.pop(); }
  bool discardPushed() override { return whole_.discardPushed(); }

 private:
  // H ← dense_ in the pattern of its nonzero 6 × 6 blocks (the bones' frames; entries when the
  // size is not a multiple of 6), diagonal blocks always stored. A bone block couples the bones
  // its joint springs, shared nodes or contacts tie: on the walking SMPL-size avatar 122 of 576
  // blocks, which AMD orders into a factor of ~2.1 k entries against the dense 10.4 k, and the
  // sparse Cholesky keeps its analysis while the pattern stays (docs/benchmarks.md).
  void blockSparse(SpMat& H) {
    const Eigen::Index n = dense_.rows();
    const int b = n % 6 == 0 ? 6 : 1;
    const Eigen::Index blocks = n / b;
    on_.assign(size_t(blocks * blocks), 0);
    for (Eigen::Index c = 0; c < blocks; ++c)
      for (Eigen::Index r = 0; r < blocks; ++r)
        if (r == c || dense_.block(r * b, c * b, b, b).cwiseAbs().maxCoeff() > 0.0) {
          on_[size_t(c * blocks + r)] = 1;
          on_[size_t(r * blocks + c)] = 1;  // symmetric, whatever rounding left in one triangle
        }
    if (on_ != pattern_ || H.rows() != n || H.cols() != n || !H.isCompressed()) {
      pattern_ = on_;
      H.resize(n, n);  // compressed, empty
      const Eigen::Index stored = Eigen::Index(std::count(on_.begin(), on_.end(), 1)) * b * b;
      H.resizeNonZeros(stored);
      Eigen::Index k = 0;
      for (Eigen::Index c = 0; c < n; ++c) {
        H.outerIndexPtr()[c] = int(k);
        for (Eigen::Index r = 0; r < blocks; ++r)
          if (on_[size_t((c / b) * blocks + r)])
            for (Eigen::Index i = r * b; i < r * b + b; ++i) H.innerIndexPtr()[k++] = int(i);
      }
      H.outerIndexPtr()[n] = int(k);
    }
    for (Eigen::Index c = 0; c < n; ++c)
      for (int k = H.outerIndexPtr()[c]; k < H.outerIndexPtr()[c + 1]; ++k)
        H.valuePtr()[k] = dense_(H.innerIndexPtr()[k], c);
  }

  Objective& whole_;
  std::vector<int> dofs_;
  std::vector<char> on_, pattern_;
  VecX step_, scratch_;
  MatX dense_;
  bool held_ = true;
  double held_energy_;
  VecX held_gradient_;
};

}  // namespace

double coarsePresolve(Objective& objective, const NewtonOptions& options, NewtonResult& result) {
  const CoarsePresolveOptions& presolve = options.coarse_presolve;
  if (presolve.max_iterations <= 0) return 0.0;
  std::vector<int> dofs;
  objective.coarseDofs(dofs);
  if (dofs.empty()) return 0.0;
  double energy = 0.0;
  VecX g;
  if (!objective.coarseEnergyAndGradient(energy, g)) return 0.0;
  const double start_norm = g.size() > 0 ? g.lpNorm<Eigen::Infinity>() : 0.0;
  NewtonOptions inner = options;
  inner.max_iterations = presolve.max_iterations;
  inner.gradient_tolerance = presolve.relative_tolerance;
  inner.linear_solver = LinearSolverType::SparseLLT;
  inner.lagged = LaggedFactorOptions{};  // a few hundred DoFs: factor every iteration
  inner.approximate_hessian = false;
  inner.coarse_presolve = CoarsePresolveOptions{};
  CoarseView view(objective, std::move(dofs), energy, std::move(g));
  const NewtonResult r = newtonSolve(view, inner, objective.coarseSolver());
  result.coarse_iterations += r.iterations;
  result.seconds_energy += r.seconds_energy;
  result.seconds_gradient += r.seconds_gradient;
  result.seconds_hessian += r.seconds_hessian;
  result.seconds_factorization += r.seconds_factorization;
  result.seconds_solve += r.seconds_solve;
  return start_norm;
}

}  // namespace flsh::detail
