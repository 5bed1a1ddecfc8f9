// Scene: simulables and colliders stepped together (scene.h): the merged state, energy and
// gradient, the skeleton's block Hessian pattern and the general one, the solver settings.
#include "flsh/solve/scene.h"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>

#include "avatar_contact.h"
#include "flsh/core/error.h"

namespace flsh {

NewtonOptions softTissueNewtonDefaults() {
  NewtonOptions options;
  options.exact_hessian = true;
  options.linear_solver = LinearSolverType::Cholmod;
  options.lagged.enabled = true;  // one 25k-DoF factorization costs ~20 preconditioned CG steps
  // Looser than the generic 1e-2: fewer refreshes of the lagged factor for the same Newton
  // iterations and accuracy (see scene.h).
  options.lagged.cg_relative_tolerance = 5e-2;
  options.gradient_tolerance = 1e-5;  // measured trade-off: see scene.h
  // Chord steps near convergence: FEM walk, 30 steps: 3.70 instead of 4.10 assemblies per
  // step for the same Newton and PCG counts, 0.0097 mm from a 1e-8 solve (0.0070 without);
  // 1e-3: 4.33 Newton iterations per step.
  options.lagged.reuse_hessian_below = 1e-4;
  options.lagged.coarse_correction = true;  // the bones exactly: see LaggedFactorOptions
  // The bones first (CoarsePresolveOptions): 30 steps, iterations on every DoF per step walk
  // 3.53 → 1.83, jumping jacks 4.87 → 2.13, jump 4.57 → 2.37, ball 3.47 → 2.67
  // (docs/benchmarks.md).
  options.coarse_presolve.max_iterations = 8;
  return options;
}

// Measured on the walking full body (rom_benchmark, docs/benchmarks.md): the exact Hessian at
// 1e-6 stays within 0.025 mm of a 1e-9 solve at the speed of the PSD form at 1e-5 (1.2 mm off);
// the lagged factor saves most factorizations (~70 against ~60 steps/s).
NewtonOptions reducedNewtonDefaults() {
  NewtonOptions options;
  options.exact_hessian = true;
  options.lagged.enabled = true;
  options.gradient_tolerance = 1e-6;
  // Chord steps near convergence: walk, 300 steps: 3.57 instead of 4.07 assemblies per step,
  // 4.07 instead of 4.04 Newton iterations, the same 0.0017 mm from a 1e-9 solve; 1e-3: 4.13
  // iterations, 3.53 assemblies.
  options.lagged.reuse_hessian_below = 1e-4;
  options.approximate_hessian = true;  // the constant soft–soft block (Scene::approximateHessian)
  // The bones exactly in PCG (see LaggedFactorOptions): the handle ROM's walk, 300 steps,
  // 27.2 → 11.2 PCG iterations and 0.65 → 0 factorizations per step, 66–70 → 76 steps/s in
  // alternating runs; the modal ROM's directions come from the approximation (no PCG):
  // unchanged.
  options.lagged.coarse_correction = true;
  // The bones first (CoarsePresolveOptions): 200 steps of jumping jacks, 47–49 → 66 steps/s
  // with handles (5.49 → 2.58 iterations on every DoF), 11 → 16 with modes; the walk no slower.
  options.coarse_presolve.max_iterations = 8;
  return options;
}

Scene::Scene(const SceneOptions& options)
    : options_(options), blocks_(std::make_unique<BlockAccumulator>()) {
  const double k = options.avatar_contact_options.stiffness;
  if (!(k >= 0.0) || !std::isfinite(k))
    throw InputError(
        "Scene: SceneOptions::avatar_contact_options.stiffness must be finite and "
        "≥ 0 (N/m³), got " +
        std::to_string(k));
}

Scene::~Scene() = default;

void Scene::addSimulable(std::shared_ptr<Simulable> simulable) {
  if (!simulable) throw InputError("Scene::addSimulable: simulable is null");
  if (!simulables_.empty()) {
    const double h0 = simulables_.front()->options().time_step;
    const double h = simulable->options().time_step;
    if (std::abs(h - h0) > 1e-12 * std::abs(h0))
      throw InputError("Scene::addSimulable: all simulables must share one time step; simulable " +
                       std::to_string(simulables_.size()) +
                       " has time_step = " + std::to_string(h) + " s, expected " +
                       std::to_string(h0) + " s (simulable 0)");
  }
  simulable->setColliders(colliders_);
  offsets_.push_back(num_dofs_);
  num_dofs_ += simulable->numDofs();
  simulables_.push_back(std::move(simulable));
  contact_data_.emplace_back();
  general_.reset();  // its DoF groups follow the simulables
}

void Scene::addCollider(const Collider& collider) {
  colliders_.push_back(collider);
  for (auto& s : simulables_) s->setColliders(colliders_);
}

void Scene::initialize() {
  for (auto& s : simulables_) s->initialize();
  for (auto& data : contact_data_)
    if (data) data->valid = false;
}

bool Scene::hasSoftTissue() const {
  for (const auto& s : simulables_)
    if (s->numDofs() > s->numBoneDofs()) return true;
  return false;
}

bool Scene::hasFemSoftTissue() const {
  for (const auto& s : simulables_)
    if (s->numDofs() > s->numBoneDofs() && !s->hasReducedModel()) return true;
  return false;
}

const NewtonOptions& Scene::newtonOptions() const {
  if (!hasSoftTissue()) return options_.newton;
  return hasFemSoftTissue() ? options_.soft_tissue_newton : options_.reduced_newton;
}

void Scene::ensureSolver() {
  // Auto, skeleton: the simplicial sparse Cholesky. The scene's Hessian is block tree-sparse
  // with a fixed pattern, so one analysis serves every step; measured on the walking SMPL-size
  // avatar it factors in ~36 µs against ~70 µs for the dense LLT (144 DoFs) and ~290 µs for
  // CHOLMOD's supernodal factor, and ~73 µs against ~380 µs (dense) for two avatars.
  // Auto, soft tissue: CHOLMOD's supernodal factor (thousands of 3 × 3 node blocks).
  if (!solver_) {
    const LinearSolverType requested = newtonOptions().linear_solver;
    // Auto, reduced model only: dense up to 1500 DoFs (the handle blocks are dense).
    const LinearSolverType type =
        requested != LinearSolverType::Auto ? requested
        : hasFemSoftTissue()                ? LinearSolverType::Cholmod
        : hasSoftTissue()
            ? (num_dofs_ <= 1500 ? LinearSolverType::Dense : LinearSolverType::Cholmod)
            : LinearSolverType::SparseLLT;
    solver_ = makeLinearSolver(type, num_dofs_);
    solver_type_ = type;
    last_solver_dofs_ = num_dofs_;
  }
}

StepStats Scene::step() { return step(StepHooks{}); }

StepStats Scene::step(const StepHooks& hooks) {
  if (simulables_.empty())
    throw Error("Scene::step: the scene has no simulables (call addSimulable first)");
  const auto start = std::chrono::steady_clock::now();
  // Kept so that a step ending in a non-finite state can be undone (below).
  std::vector<SimulableStep> before;
  before.reserve(simulables_.size());
  for (auto& s : simulables_) before.push_back(s->saveStep());
  for (auto& s : simulables_) s->preUpdate();
  if (hooks.after_pre_update) hooks.after_pre_update();
  ensureSolver();
  if (options_.lower_energy_start && hasSoftTissue()) {
    const double at_prediction = energy();
    for (auto& s : simulables_) s->setStepStart(Simulable::StepStart::PreviousState);
    // A non-finite energy at the prediction keeps the previous state.
    if (at_prediction <= energy())
      for (auto& s : simulables_) s->setStepStart(Simulable::StepStart::Prediction);
  }
  StepStats stats;
  stats.newton = newtonSolve(*this, newtonOptions(), solver_.get());
  // Newton rejects non-finite energies, but a state can still overflow where no energy looks
  // (e.g. a rotation): never hand a NaN state on. The scene goes back to before the step.
  for (size_t i = 0; i < simulables_.size(); ++i) {
    if (simulables_[i]->getState().allFinite()) continue;
    for (size_t j = 0; j < simulables_.size(); ++j) simulables_[j]->restoreStep(before[j]);
    throw Error("Scene::step: simulable " + std::to_string(i) +
                " has a non-finite state after the step to t = " +
                std::to_string(before[i].time + simulables_[i]->options().time_step) +
                " s (Newton: " + stats.newton.message +
                "); the scene is restored to its state before the step");
  }
  // Newton's last evaluation is the gradient at the final state, so these counts belong to it.
  for (auto& s : simulables_) stats.active_contacts += s->stats().active_contacts;
  stats.active_contacts += avatar_contacts_;
  if (hooks.before_post_update) hooks.before_post_update(stats.newton);
  for (auto& s : simulables_) s->postUpdate();
  stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return stats;
}

double Scene::time() const { return simulables_.empty() ? 0.0 : simulables_.front()->time(); }

void Scene::setStatic(bool on) {
  for (auto& s : simulables_) s->setStatic(on);
}

int Scene::numDofs() const { return num_dofs_; }

bool Scene::avatarContactActive() const {
  return options_.avatar_contact && simulables_.size() >= 2 &&
         options_.avatar_contact_options.stiffness > 0.0;
}

double Scene::energy() {
  double e = 0.0;
  for (auto& s : simulables_) e += s->getDynamicEnergyScalar() + s->getPotentialEnergyScalar();
  if (avatarContactActive()) e += avatarContactEnergy(nullptr, nullptr, true);
  return e;
}

void Scene::gradient(VecX& g) {
  double energy = 0.0;  // the same passes give it (Simulable::getGradientVector does the same)
  energyAndGradient(energy, g);
}

bool Scene::energyAndGradient(double& energy, VecX& g) {
  g.setZero(num_dofs_);
  energy = 0.0;
  for (size_t i = 0; i < simulables_.size(); ++i)
    energy += simulables_[i]->getEnergyAndGradientVector(g, offsets_[i]);
  if (avatarContactActive()) energy += avatarContactEnergy(&g, nullptr, true);
  return true;
}

void Scene::hessian(SpMat& H, bool psd) {
  if (usesGeneralPattern()) {
    assembleGeneral(H, psd, false);
    return;
  }
  triplets_.clear();
  for (size_t i = 0; i < simulables_.size(); ++i) {
    simulables_[i]->getDynamicHessianTripletVector(triplets_, offsets_[i], psd);
    simulables_[i]->getPotentialHessianTripletVector(triplets_, offsets_[i], psd);
  }
  if (avatarContactActive()) avatarContactEnergy(nullptr, &triplets_, psd);
  if (!fillHessian(H)) {
    // A block outside the pattern (a new avatar–avatar pair): grow the pattern once.
    rebuildHessianPattern();
    if (!fillHessian(H)) throw Error("Scene::hessian: the Hessian pattern misses an entry");
  }
}

bool Scene::approximateHessian(SpMat& H) {
  if (!usesGeneralPattern()) return false;  // the skeleton's Hessian is cheap already
  if (std::none_of(simulables_.begin(), simulables_.end(),
                   [](const auto& s) { return s->hasApproximateHessian(); }))
    return false;
  assembleGeneral(H, false, true);
  return true;
}

void Scene::assembleGeneral(SpMat& H, bool psd, bool approximate) {
  // One cached segment per energy kind, so a term whose triplet count changes (contacts) does
  // not move the others' value slots; the approximate form has the exact form's layout.
  triplets_.clear();
  segment_end_.clear();
  fixed_blocks_.clear();
  for (size_t i = 0; i < simulables_.size(); ++i) {
    // The FEM's elastic node pairs and its bone–tissue coupling come as fixed blocks (the
    // same lists in the same order every call): no 9 triplets per block.
    size_t potential_start = 0;
    if (!approximate || !simulables_[i]->getApproximateHessianTripletVector(
                            triplets_, fixed_blocks_, offsets_[i], &potential_start))
      potential_start =
          simulables_[i]->getHessianTripletVector(triplets_, fixed_blocks_, offsets_[i], psd);
    segment_end_.push_back(potential_start);
    segment_end_.push_back(triplets_.size());
  }
  if (avatarContactActive()) avatarContactEnergy(nullptr, &triplets_, psd);
  segment_end_.push_back(triplets_.size());
  if (!general_) setUpGeneralPattern();
  general_->assemble(triplets_, segment_end_, fixed_blocks_, num_dofs_, H);
}

// Writes the triplets into H with the fixed pattern (H takes the pattern if it has another
// one). False if a triplet falls outside the pattern.
bool Scene::fillHessian(SpMat& H) const {
  const int n = num_dofs_, bones = n / 6;
  if (hessian_pattern_.rows() != n) return false;
  const SpMat& P = hessian_pattern_;
  resetToPattern(P, H);
  double* values = H.valuePtr();
  const int* outer = H.outerIndexPtr();
  const size_t count = triplets_.size();
  if (fill_key_.size() < count) {
    fill_key_.resize(count, -1);
    fill_index_.resize(count, 0);
  }
  for (size_t k = 0; k < count; ++k) {
    const Triplet& t = triplets_[k];
    const int r = t.row(), c = t.col();
    const long long key = (long long)r * n + c;
    if (key != fill_key_[k]) {
      const int rank = block_rank_[size_t(r / 6) * bones + c / 6];
      if (rank < 0) return false;
      fill_key_[k] = key;
      fill_index_[k] = outer[c] + 6 * rank + r % 6;
    }
    values[fill_index_[k]] += t.value();
  }
  return true;
}

void Scene::rebuildHessianPattern() {
  const int n = num_dofs_, bones = n / 6;
  // Block pairs (a, b): the old pattern's, the current triplets', every bone's diagonal, and
  // within each simulable every pair of bones that share a skinned vertex.
  std::vector<char> present(size_t(bones) * bones, 0);
  if (block_rank_.size() == present.size())
    for (size_t k = 0; k < present.size(); ++k) present[k] = block_rank_[k] >= 0;
  for (const Triplet& t : triplets_) present[size_t(t.row() / 6) * bones + t.col() / 6] = 1;
  for (int b = 0; b < bones; ++b) present[size_t(b) * bones + b] = 1;
  for (size_t i = 0; i < simulables_.size(); ++i) {
    const Simulable& sim = *simulables_[i];
    const MatX& W = sim.avatar().body().weights;  // #V × bones
    if (sim.numDofs() != 6 * W.cols()) continue;
    const int first = offsets_[i] / 6, local_bones = int(W.cols());
    std::vector<int> influencing;
    for (int v = 0; v < W.rows(); ++v) {
      influencing.clear();
      for (int b = 0; b < local_bones; ++b)
        if (W(v, b) != 0.0) influencing.push_back(first + b);
      for (int a : influencing)
        for (int b : influencing) present[size_t(a) * bones + b] = 1;
    }
  }
  std::vector<Triplet> structure;
  block_rank_.assign(present.size(), -1);
  for (int bc = 0; bc < bones; ++bc) {
    int rank = 0;
    for (int br = 0; br < bones; ++br) {
      if (!present[size_t(br) * bones + bc]) continue;
      block_rank_[size_t(br) * bones + bc] = rank++;
      for (int c = 0; c < 6; ++c)
        for (int r = 0; r < 6; ++r) structure.emplace_back(6 * br + r, 6 * bc + c, 0.0);
    }
  }
  hessian_pattern_.resize(n, n);
  hessian_pattern_.setFromTriplets(structure.begin(), structure.end());
  hessian_pattern_.makeCompressed();
  fill_key_.clear();  // value indices refer to the old pattern
}

bool Scene::usesGeneralPattern() const {
  if (options_.general_hessian_pattern) return true;
  for (const auto& s : simulables_)
    if (s->numDofs() != s->numBoneDofs()) return true;  // not only bone blocks
  return false;
}

void Scene::setUpGeneralPattern() {
  // DoF groups: 6 per bone, 3 per soft-tissue node (leftover DoFs of another layout: 1 each).
  std::vector<int> group_start{0};
  std::vector<int> first_group(simulables_.size());
  for (size_t i = 0; i < simulables_.size(); ++i) {
    const Simulable& sim = *simulables_[i];
    first_group[i] = int(group_start.size()) - 1;
    const int end = offsets_[i] + sim.numDofs();
    int dof = offsets_[i];
    for (; dof + 6 <= offsets_[i] + sim.numBoneDofs(); dof += 6) group_start.push_back(dof + 6);
    for (; dof + 3 <= end && dof >= offsets_[i] + sim.numBoneDofs(); dof += 3)
      group_start.push_back(dof + 3);
    for (; dof < end; ++dof) group_start.push_back(dof + 1);
  }
  general_ = std::make_unique<HessianAssembler>();
  general_->setGroups(group_start);
  // The dense solver gets a dense matrix anyway (reduced-model scenes: the handle block is
  // dense): full storage spares the slot cache (rom_benchmark: the fill was ~20 % of a step).
  if (solver_ && solver_type_ == LinearSolverType::Dense &&
      num_dofs_ <= HessianAssembler::kMaxDenseDofs) {
    general_->setDense(true);
    return;
  }
  // Couplings collider contacts create (as for the block pattern): within each simulable,
  // every pair of bones that share a surface vertex, and each soft surface vertex's u with
  // those bones.
  std::vector<std::pair<int, int>> blocks;
  std::vector<int> influencing;
  std::vector<char> pair_seen;
  for (size_t i = 0; i < simulables_.size(); ++i) {
    const Simulable& sim = *simulables_[i];
    const MatX& W = sim.avatar().body().weights;  // #V × bones
    const int bones = int(W.cols());
    if (sim.numBoneDofs() != 6 * bones) continue;
    const int bone0 = first_group[i];
    pair_seen.assign(size_t(bones) * bones, 0);
    const bool soft = sim.numDofs() > sim.numBoneDofs();
    for (int v = 0; v < W.rows(); ++v) {
      influencing.clear();
      for (int b = 0; b < bones; ++b)
        if (W(v, b) != 0.0) influencing.push_back(b);
      for (int a : influencing)
        for (int b : influencing)
          if (!pair_seen[size_t(a) * bones + b]) {
            pair_seen[size_t(a) * bones + b] = 1;
            blocks.emplace_back(bone0 + a, bone0 + b);
          }
      if (!soft) continue;
      // The groups of the state entries u_v is made of (groups of 3 after the bones).
      for (const auto& entry : sim.nodeDisplacementBasis(v)) {
        const int group = bone0 + bones + (entry.first - sim.numBoneDofs()) / 3;
        for (int b : influencing) {
          blocks.emplace_back(group, bone0 + b);
          blocks.emplace_back(bone0 + b, group);
        }
      }
    }
  }
  general_->addBlocks(blocks);
}

void Scene::step(const VecX& dq) {
  if (dq.size() != num_dofs_)
    throw InputError("Scene::step: dq must have numDofs() = " + std::to_string(num_dofs_) +
                     " entries, got " + std::to_string(dq.size()));
  for (size_t i = 0; i < simulables_.size(); ++i)
    simulables_[i]->updateState(dq.segment(offsets_[i], simulables_[i]->numDofs()));
}

void Scene::push() {
  for (auto& s : simulables_) s->pushState();
  ++stack_depth_;
}

void Scene::pop() {
  if (stack_depth_ == 0) throw Error("Scene::pop: no state was pushed");
  for (auto& s : simulables_) s->popState();
  --stack_depth_;
}

// Keeps the current (accepted) states and forgets the saved ones: no pop-and-reapply.
bool Scene::discardPushed() {
  if (stack_depth_ == 0) throw Error("Scene::discardPushed: no state was pushed");
  for (auto& s : simulables_) s->discardState();
  --stack_depth_;
  return true;
}

void Scene::fixKinematic(VecX& g, SpMat* H) {
  bool any_kinematic = false;
  for (size_t i = 0; i < simulables_.size(); ++i) {
    simulables_[i]->fixVectorKinematic(g, offsets_[i]);
    any_kinematic = any_kinematic || !simulables_[i]->options().kinematic_bones.empty();
  }
  if (!H || !any_kinematic) return;
  // In place, keeping the pattern (and the solver's analysis): kinematic rows and columns
  // become those of the identity. hessian() always stores the diagonal.
  std::vector<char> kinematic;
  markKinematicBones(kinematic);
  for (int k = 0; k < H->outerSize(); ++k)
    for (SpMat::InnerIterator it(*H, k); it; ++it)
      if (kinematic[it.row()] || kinematic[it.col()])
        it.valueRef() = it.row() == it.col() ? 1.0 : 0.0;
}

void Scene::markKinematicBones(std::vector<char>& kinematic) const {
  kinematic.assign(size_t(num_dofs_), 0);
  for (size_t i = 0; i < simulables_.size(); ++i)
    for (int b : simulables_[i]->options().kinematic_bones)
      std::fill_n(kinematic.begin() + offsets_[i] + 6 * b, 6, 1);
}

void Scene::coarseDofs(std::vector<int>& dofs) const {
  dofs.clear();
  for (size_t i = 0; i < simulables_.size(); ++i)
    for (int k = 0; k < simulables_[i]->numBoneDofs(); ++k) dofs.push_back(offsets_[i] + k);
}

}  // namespace flsh
