// Tape of converged steps (one exact-Hessian factor each, one shared ordering; or snapshots,
// each sweep solving by PCG with a nearby step's factor) and the reverse and forward sweeps over
// it.
#include "flsh/diff/tape.h"

#include <Eigen/OrderingMethods>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseLU>
#include <cmath>
#include <cstdio>
#include <string>

#include "flsh/core/error.h"
#include "flsh/solve/linear_solver.h"
#include "solve/coarse_correction.h"
#include "solve/preconditioned_cg.h"

namespace flsh {

namespace {

using Permutation = Eigen::PermutationMatrix<Eigen::Dynamic, Eigen::Dynamic, int>;
using NaturalLLT = Eigen::SimplicialLLT<SpMat, Eigen::Lower, Eigen::NaturalOrdering<int>>;
using NaturalLDLT = Eigen::SimplicialLDLT<SpMat, Eigen::Lower, Eigen::NaturalOrdering<int>>;

// Pivots below this fraction of the largest count as zero (the solver's floor as well).
constexpr double kRelativePivotFloor = 1e-14;
// From this many unknowns a positive definite H is factored by CHOLMOD's supernodal Cholesky
// (the FEM soft skeleton's: about 1.3 s per step for Eigen's simplicial factor of the 26 k-DoF
// walking body, docs/benchmarks.md); below (the skeleton, the ROM's few hundred DoFs) the
// simplicial factor. The small FEM bodies of the tests (~2 600 DoFs) take the supernodal path.
constexpr int kSupernodalFrom = 2000;

// The exact Hessian of one step, factored. P is the shared fill-reducing permutation: the
// factors are of P H Pᵀ (lower triangle), so the symbolic work per step is only the elimination
// tree of a fixed ordering.
struct StepFactor {
  std::unique_ptr<LinearSolver> supernodal;  // CHOLMOD, positive definite H of kSupernodalFrom+
  std::unique_ptr<NaturalLLT> llt;
  std::unique_ptr<NaturalLDLT> ldlt;
  std::unique_ptr<Eigen::SparseLU<SpMat, Eigen::COLAMDOrdering<int>>> lu;
  const Permutation* P = nullptr;
  const Permutation* P_inverse = nullptr;

  /// `reuse`: a CHOLMOD solver whose symbolic analysis may serve (the previous step's), or null.
  /// Returns how H was factored (TapeStepInfo::factorization).
  std::string factorize(const SpMat& H, const Permutation& perm, const Permutation& perm_inv,
                        std::unique_ptr<LinearSolver> reuse = nullptr) {
    P = &perm;
    P_inverse = &perm_inv;
    if (H.rows() >= kSupernodalFrom) {
      supernodal =
          reuse ? std::move(reuse) : makeLinearSolver(LinearSolverType::Cholmod, int(H.rows()));
      if (supernodal->factorize(H)) return "llt";
      supernodal.reset();
    }
    SpMat permuted(H.rows(), H.cols());
    permuted.selfadjointView<Eigen::Lower>() = H.selfadjointView<Eigen::Lower>().twistedBy(perm);
    llt = std::make_unique<NaturalLLT>(permuted);
    if (llt->info() == Eigen::Success) {
      const VecX pivots = llt->matrixL().nestedExpression().diagonal();
      if (pivots.minCoeff() > std::sqrt(kRelativePivotFloor) * pivots.maxCoeff()) return "llt";
    }
    llt.reset();
    ldlt = std::make_unique<NaturalLDLT>(permuted);
    if (ldlt->info() == Eigen::Success) {
      const VecX d = ldlt->vectorD().cwiseAbs();
      if (d.minCoeff() > kRelativePivotFloor * d.maxCoeff()) return "ldlt";
    }
    ldlt.reset();
    SpMat full = H;
    full.makeCompressed();
    lu = std::make_unique<Eigen::SparseLU<SpMat, Eigen::COLAMDOrdering<int>>>();
    lu->compute(full);
    if (lu->info() == Eigen::Success) {
      // Usable when it reproduces a known solution (a nearly singular H would not).
      const VecX ones = VecX::Ones(H.rows());
      const VecX x = lu->solve(VecX(full * ones));
      if (x.allFinite() && (x - ones).cwiseAbs().maxCoeff() < 1e-6) return "lu";
    }
    lu.reset();
    return "singular";
  }

  VecX solve(const VecX& b) const {
    if (supernodal) return supernodal->solve(b);
    if (llt) return *P_inverse * llt->solve(*P * b);
    if (ldlt) return *P_inverse * ldlt->solve(*P * b);
    return lu->solve(b);
  }
};

void checkGroups(const std::vector<ParameterGroupInfo>& groups, const char* who) {
  for (const ParameterGroupInfo& g : groups)
    if (g.size < 0)
      throw Error(std::string(who) + ": parameter group '" + g.name + "' has size < 0");
}

}  // namespace

struct Tape::Impl {
  int n = -1;
  Storage storage = Storage::Factors, recording = Storage::Factors;
  TapeSolveOptions solve_options;
  std::vector<int> coarse_dofs;  // the model's (AdjointModel::coarseDofs), at recordInitial
  Permutation P, P_inverse;
  // Storage::Snapshots: the factor of step `current_step` (0: none).
  std::unique_ptr<StepFactor> current;
  int current_step = 0;
  // Storage::Snapshots with PCG: step `pcg_step`'s exact Hessian H (0: none), its coarse level,
  // and whether the next prepared step factors (a sweep's first, or after a slow PCG).
  SpMat H;
  int pcg_step = 0;
  bool refactor_next = true;
  bool sweep_iterative = true;  // this sweep may use PCG (few right-hand sides)
  detail::CoarseCorrection coarse;
  detail::CgWorkspace cg;

  void exactHessian(const AdjointModel& model, SpMat& out) const {
    model.exactHessian(out);
    if (out.rows() != n || out.cols() != n)
      throw Error("Tape: the model's exact Hessian is " +
                  shapeString({long(out.rows()), long(out.cols())}) + ", expected " +
                  shapeString({long(n), long(n)}));
  }

  // The step's exact Hessian factored; `reuse`: a factor whose CHOLMOD analysis may serve.
  std::unique_ptr<StepFactor> factor(const AdjointModel& model, std::string& how,
                                     std::unique_ptr<StepFactor> reuse = nullptr) {
    SpMat step_hessian;
    exactHessian(model, step_hessian);
    return factorMatrix(step_hessian, how, std::move(reuse));
  }

  // H factored (the ordering from the first matrix factored).
  std::unique_ptr<StepFactor> factorMatrix(const SpMat& H, std::string& how,
                                           std::unique_ptr<StepFactor> reuse) {
    if (P.size() != n) {
      // One fill-reducing ordering for every step (any ordering is valid for any pattern; the
      // skeleton's pattern barely changes between steps).
      const SpMat full = H.selfadjointView<Eigen::Lower>();
      Eigen::AMDOrdering<int> amd;
      amd(full, P_inverse);
      P = P_inverse.inverse();
    }
    auto f = std::make_unique<StepFactor>();
    how = f->factorize(H, P, P_inverse, reuse ? std::move(reuse->supernodal) : nullptr);
    return f;
  }

  // The held factor may precondition PCG on later steps' Hessians: large enough for PCG, and
  // a CHOLMOD factor (positive definite, with its single-precision copy).
  bool factorPreconditions() const {
    return solve_options.iterative && sweep_iterative && n >= kSupernodalFrom && current &&
           current->supernodal;
  }
  std::unique_ptr<StepSnapshot> initial;
  std::vector<std::unique_ptr<StepSnapshot>> snapshots;
  std::vector<std::unique_ptr<StepFactor>> factors;
  std::vector<TapeStepInfo> infos;
};

Tape::Tape() : impl_(std::make_unique<Impl>()) {}
Tape::~Tape() = default;
Tape::Tape(Tape&&) noexcept = default;
Tape& Tape::operator=(Tape&&) noexcept = default;

void Tape::clear() {
  impl_->initial.reset();
  impl_->snapshots.clear();
  impl_->factors.clear();
  impl_->infos.clear();
  impl_->current.reset();
  impl_->current_step = 0;
  impl_->H = SpMat();
  impl_->pcg_step = 0;
  impl_->refactor_next = true;
}

void Tape::recordInitial(const AdjointModel& model) {
  clear();
  impl_->recording = impl_->storage;
  impl_->n = model.numDofs();
  model.coarseDofs(impl_->coarse_dofs);
  impl_->initial = model.saveStep();
}

void Tape::recordStep(const AdjointModel& model, TapeStepInfo info) {
  Impl& m = *impl_;
  if (!m.initial)
    throw Error("Tape::recordStep: no initial conditions recorded (call recordInitial first)");
  if (model.numDofs() != m.n)
    throw InputError("Tape::recordStep: the model has " + std::to_string(model.numDofs()) +
                     " DoFs, expected the " + std::to_string(m.n) + " of the recorded steps");
  if (m.recording == Storage::Factors) {
    m.factors.push_back(m.factor(model, info.factorization));
  } else {
    info.factorization = "deferred";
    m.factors.push_back(nullptr);
  }
  m.snapshots.push_back(model.saveStep());
  m.infos.push_back(std::move(info));
}

void Tape::setStorage(Storage storage) { impl_->storage = storage; }
Tape::Storage Tape::storage() const { return impl_->storage; }

void Tape::setSolveOptions(const TapeSolveOptions& options) {
  const auto bad = [](const std::string& name, const std::string& expected, double value) {
    char text[64];
    std::snprintf(text, sizeof(text), "%g", value);
    throw InputError("Tape::setSolveOptions: TapeSolveOptions::" + name + " must be " + expected +
                     ", got " + text);
  };
  if (!(options.relative_tolerance > 0.0 && options.relative_tolerance < 1.0))
    bad("relative_tolerance", "in (0, 1)", options.relative_tolerance);
  if (options.max_iterations < 1) bad("max_iterations", "≥ 1", options.max_iterations);
  if (options.refactor_after_iterations < 0)
    bad("refactor_after_iterations", "≥ 0", options.refactor_after_iterations);
  if (options.max_right_hand_sides < 1)
    bad("max_right_hand_sides", "≥ 1", options.max_right_hand_sides);
  impl_->solve_options = options;
}

const TapeSolveOptions& Tape::solveOptions() const { return impl_->solve_options; }

void Tape::beginSweep(int right_hand_sides) const {
  impl_->pcg_step = 0;
  impl_->refactor_next = true;
  impl_->sweep_iterative = right_hand_sides <= impl_->solve_options.max_right_hand_sides;
}

void Tape::prepareStep(int t, const AdjointModel& model) const {
  stepInfo(t);  // range check
  Impl& m = *impl_;
  if (m.factors[size_t(t - 1)] || m.pcg_step == t) return;
  TapeStepInfo& info = m.infos[size_t(t - 1)];
  if (m.current_step != t && !m.refactor_next && m.factorPreconditions()) {
    // PCG on this step's own exact Hessian, preconditioned by the held factor (solve()).
    m.exactHessian(model, m.H);
    m.H.makeCompressed();
    m.coarse.build(m.H, m.coarse_dofs);
    m.pcg_step = t;
    info.factorization = "pcg";
    info.cg_iterations = 0;
    return;
  }
  m.pcg_step = 0;
  info.cg_iterations = 0;
  if (m.current_step != t) {
    m.current_step = 0;
    std::string how;
    m.current = m.factor(model, how, std::move(m.current));
    m.current_step = t;
    info.factorization = how;
  }
  m.refactor_next = false;
}

int Tape::numSteps() const { return int(impl_->snapshots.size()); }
int Tape::numDofs() const { return impl_->n; }
bool Tape::hasInitial() const { return bool(impl_->initial); }

const TapeStepInfo& Tape::stepInfo(int t) const {
  if (t < 1 || t > numSteps())
    throw InputError("Tape::stepInfo: step " + std::to_string(t) + " out of range [1, " +
                     std::to_string(numSteps()) + "]");
  return impl_->infos[t - 1];
}

const StepSnapshot& Tape::initialSnapshot() const {
  if (!impl_->initial) throw Error("Tape: no initial conditions recorded");
  return *impl_->initial;
}

const StepSnapshot& Tape::stepSnapshot(int t) const {
  if (t < 1 || t > numSteps())
    throw InputError("Tape::stepSnapshot: step " + std::to_string(t) + " out of range [1, " +
                     std::to_string(numSteps()) + "]");
  return *impl_->snapshots[t - 1];
}

VecX Tape::solve(int t, const VecX& b) const {
  stepInfo(t);  // range check
  Impl& m = *impl_;
  TapeStepInfo& info = m.infos[size_t(t - 1)];
  if (b.size() != m.n)
    throw InputError("Tape::solve: b has " + std::to_string(b.size()) + " entries, expected " +
                     std::to_string(m.n));
  if (m.pcg_step == t) {  // set by prepareStep on snapshots only
    const TapeSolveOptions& o = m.solve_options;
    const double norm = b.norm();
    if (norm == 0.0) return VecX::Zero(m.n);
    VecX x;
    int iterations = 0;
    const detail::CgOutcome outcome =
        detail::preconditionedCg(m.H, b, o.relative_tolerance * norm, o.max_iterations,
                                 *m.current->supernodal, true, &m.coarse, x, m.cg, iterations);
    info.cg_iterations += iterations;
    if (outcome == detail::CgOutcome::Converged && x.allFinite()) {
      if (iterations > o.refactor_after_iterations) m.refactor_next = true;
      return x;
    }
    // PCG failed (H_t indefinite, or too slow): factor H_t and solve with it.
    std::string how;
    m.current_step = 0;
    m.current = m.factorMatrix(m.H, how, std::move(m.current));
    m.current_step = t;
    m.pcg_step = 0;
    m.refactor_next = !m.factorPreconditions();
    info.factorization = how;
  }
  const StepFactor* factor = m.factors[size_t(t - 1)]
                                 ? m.factors[size_t(t - 1)].get()
                                 : (m.current_step == t ? m.current.get() : nullptr);
  if (!factor)
    throw Error("Tape::solve: step " + std::to_string(t) +
                "'s factor is not kept (Storage::Snapshots): call prepareStep(t, model) with the "
                "model restored to the step first");
  if (info.factorization == "singular")
    throw Error("Tape: the exact Hessian of step " + std::to_string(t) +
                " is singular (the converged state is not a strict local minimum), so the "
                "step's derivatives are undefined");
  return factor->solve(b);
}

// ---- sweeps --------------------------------------------------------------------------------

namespace {

// Restores the model's step data on scope exit (also when a sweep throws).
class RestoreOnExit {
 public:
  explicit RestoreOnExit(AdjointModel& model) : model_(model), saved_(model.saveStep()) {}
  ~RestoreOnExit() { model_.restoreStep(*saved_); }

 private:
  AdjointModel& model_;
  std::unique_ptr<StepSnapshot> saved_;
};

void requireTape(const Tape& tape, const AdjointModel& model, const char* who) {
  if (!tape.hasInitial() || tape.numSteps() == 0)
    throw Error(std::string(who) + ": the tape holds no steps (record a rollout first)");
  if (tape.numDofs() != model.numDofs())
    throw InputError(std::string(who) + ": the tape has " + std::to_string(tape.numDofs()) +
                     " DoFs per step, the model " + std::to_string(model.numDofs()));
}

}  // namespace

AdjointResult adjointSweep(AdjointModel& model, const Tape& tape,
                           const Eigen::Ref<const RowMatX>& state_cotangents) {
  const char* who = "adjointSweep";
  requireTape(tape, model, who);
  const int T = tape.numSteps(), n = model.numDofs();
  if (state_cotangents.rows() != T || state_cotangents.cols() != n)
    throw InputError(std::string(who) + ": state_cotangents has shape " +
                     shapeString({long(state_cotangents.rows()), long(state_cotangents.cols())}) +
                     ", expected " + shapeString({long(T), long(n)}) + " (steps × DoFs)");
  if (!state_cotangents.allFinite())
    throw InputError(std::string(who) + ": state_cotangents contains NaN or Inf");
  const std::vector<ParameterGroupInfo> groups = model.parameterGroups();
  checkGroups(groups, who);
  AdjointResult result;
  result.global.resize(groups.size());
  result.per_step.resize(groups.size());
  for (size_t g = 0; g < groups.size(); ++g) {
    if (groups[g].per_step)
      result.per_step[g] = RowMatX::Zero(T, groups[g].size);
    else
      result.global[g] = VecX::Zero(groups[g].size);
  }
  RestoreOnExit restore(model);
  tape.beginSweep();
  // a[k] holds ā for q_{t}, q_{t−1}, q_{t−2} while sweeping: a_next = ā_{t−1}, a_next2 = ā_{t−2}.
  VecX a_t = VecX::Zero(n), a_prev = VecX::Zero(n), a_prev2 = VecX::Zero(n);
  VecX a_n, a_nm1;
  std::vector<VecX> products;
  for (int t = T; t >= 1; --t) {
    model.restoreStep(tape.stepSnapshot(t));
    tape.prepareStep(t, model);
    a_t += model.stateToIncrementCotangent(state_cotangents.row(t - 1).transpose());
    const VecX lambda = tape.solve(t, a_t);
    // Products with λ only: no ∂g/∂p or ∂g/∂q_{n−k} matrices are formed.
    model.previousStatesVJP(lambda, a_n, a_nm1);
    a_prev -= a_n;
    a_prev2 -= a_nm1;
    model.parameterVJPs(lambda, products);
    for (size_t g = 0; g < groups.size(); ++g) {
      if (groups[g].size == 0) continue;
      if (groups[g].per_step)
        result.per_step[g].row(t - 1) -= products[g].transpose();
      else
        result.global[g] -= products[g];
    }
    // Shift: step t − 1's accumulated cotangent becomes the current one.
    a_t = a_prev;
    a_prev = a_prev2;
    a_prev2.setZero();
  }
  model.finishParameterVJPs(result.global);
  // Now a_t = ā_0 and a_prev = ā_{−1}.
  model.restoreStep(tape.initialSnapshot());
  result.initial_velocity = model.initialPreviousStateCotangent(a_prev, a_t);
  result.initial_state_increment = a_t;
  result.initial_state = model.incrementToStateCotangent(a_t);
  return result;
}

std::vector<RowMatX> tangentSweep(AdjointModel& model, const Tape& tape,
                                  const std::vector<TangentDirection>& directions,
                                  std::vector<VecX>* initial_states) {
  const char* who = "tangentSweep";
  requireTape(tape, model, who);
  const int T = tape.numSteps(), n = model.numDofs();
  const std::vector<ParameterGroupInfo> groups = model.parameterGroups();
  checkGroups(groups, who);
  const size_t D = directions.size();
  // Validate every direction before touching the model.
  for (size_t d = 0; d < D; ++d) {
    const TangentDirection& dir = directions[d];
    const std::string where = std::string(who) + ": direction " + std::to_string(d) + ": ";
    if (!dir.global.empty() && dir.global.size() != groups.size())
      throw InputError(where + "global has " + std::to_string(dir.global.size()) +
                       " groups, expected " + std::to_string(groups.size()) + " (or none)");
    if (!dir.per_step.empty() && dir.per_step.size() != groups.size())
      throw InputError(where + "per_step has " + std::to_string(dir.per_step.size()) +
                       " groups, expected " + std::to_string(groups.size()) + " (or none)");
    for (size_t g = 0; g < groups.size(); ++g) {
      if (!dir.global.empty() && dir.global[g].size() != 0) {
        if (groups[g].per_step || dir.global[g].size() != groups[g].size)
          throw InputError(where + "global[" + groups[g].name + "] has " +
                           std::to_string(dir.global[g].size()) + " values, expected " +
                           (groups[g].per_step ? std::string("none (a per-step group)")
                                               : std::to_string(groups[g].size)));
        if (!dir.global[g].allFinite())
          throw InputError(where + "global[" + groups[g].name + "] contains NaN or Inf");
      }
      if (!dir.per_step.empty() && dir.per_step[g].size() != 0) {
        if (!groups[g].per_step || dir.per_step[g].rows() != T ||
            dir.per_step[g].cols() != groups[g].size)
          throw InputError(
              where + "per_step[" + groups[g].name + "] has shape " +
              shapeString({long(dir.per_step[g].rows()), long(dir.per_step[g].cols())}) +
              ", expected " +
              (groups[g].per_step ? shapeString({long(T), long(groups[g].size)})
                                  : std::string("none (a rollout-wide group)")));
        if (!dir.per_step[g].allFinite())
          throw InputError(where + "per_step[" + groups[g].name + "] contains NaN or Inf");
      }
    }
    for (const auto& [name, v] :
         {std::pair<const char*, const VecX*>{"initial_state", &dir.initial_state},
          {"initial_state_increment", &dir.initial_state_increment},
          {"initial_velocity", &dir.initial_velocity}}) {
      if (v->size() != 0 && v->size() != n)
        throw InputError(where + name + " has " + std::to_string(v->size()) + " values, expected " +
                         std::to_string(n) + " (or none)");
      if (!v->allFinite()) throw InputError(where + name + " contains NaN or Inf");
    }
  }
  RestoreOnExit restore(model);
  tape.beginSweep(int(D));
  // Increments of q_{t−1} and q_{t−2} per direction.
  std::vector<VecX> dq_prev(D), dq_prev2(D);
  model.restoreStep(tape.initialSnapshot());
  if (initial_states) initial_states->assign(D, VecX());
  for (size_t d = 0; d < D; ++d) {
    const TangentDirection& dir = directions[d];
    VecX dq0 = VecX::Zero(n);
    if (dir.initial_state.size()) dq0 += model.stateToIncrementTangent(dir.initial_state);
    if (dir.initial_state_increment.size()) dq0 += dir.initial_state_increment;
    const VecX dv0 = dir.initial_velocity.size() ? dir.initial_velocity : VecX(VecX::Zero(n));
    dq_prev2[d] = model.initialPreviousStateTangent(dq0, dv0);
    if (initial_states) (*initial_states)[d] = model.incrementToStateTangent(dq0);
    dq_prev[d] = dq0;
  }
  std::vector<RowMatX> out(D, RowMatX::Zero(T, n));
  // This step's parameter directions (per-step groups: row t − 1) as pointers for parameterJVPs.
  std::vector<std::vector<VecX>> step_rows(D, std::vector<VecX>(groups.size()));
  std::vector<std::vector<const VecX*>> step_directions(
      D, std::vector<const VecX*>(groups.size(), nullptr));
  std::vector<VecX> products;
  for (int t = 1; t <= T; ++t) {
    model.restoreStep(tape.stepSnapshot(t));
    tape.prepareStep(t, model);
    for (size_t d = 0; d < D; ++d) {
      const TangentDirection& dir = directions[d];
      for (size_t g = 0; g < groups.size(); ++g) {
        step_directions[d][g] = nullptr;
        if (groups[g].per_step) {
          if (!dir.per_step.empty() && dir.per_step[g].size()) {
            step_rows[d][g] = dir.per_step[g].row(t - 1).transpose();
            step_directions[d][g] = &step_rows[d][g];
          }
        } else if (!dir.global.empty() && dir.global[g].size()) {
          step_directions[d][g] = &dir.global[g];
        }
      }
    }
    model.parameterJVPs(step_directions, products);
    for (size_t d = 0; d < D; ++d) {
      const VecX rhs = model.previousStatesJVP(dq_prev[d], dq_prev2[d]) + products[d];
      const VecX dq = -tape.solve(t, rhs);
      out[d].row(t - 1) = model.incrementToStateTangent(dq).transpose();
      dq_prev2[d] = std::move(dq_prev[d]);
      dq_prev[d] = dq;
    }
  }
  return out;
}

}  // namespace flsh
