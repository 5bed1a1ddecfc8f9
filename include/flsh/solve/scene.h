// Scene: several simulables (avatars) and colliders stepped together. Their states are merged
// into one vector (simulable i at offset(i)) and one sparse Hessian; avatar–avatar contact
// couples them through each avatar's capsules (one per bone, moving with the bone).
//
// Two Hessian assemblies: skeleton-only scenes keep a pattern of whole 6 × 6 bone blocks (the
// fastest path, a few µs per evaluation); scenes with soft-tissue DoFs (a simulable with
// numDofs() > numBoneDofs()) or SceneOptions::general_hessian_pattern use a HessianAssembler
// (hessian_assembler.h: general CSC pattern grown by DoF-group blocks: 6 per bone, 3 per
// soft-tissue node). Avatar–avatar contact is in src/solve/avatar_contact.cpp.
#pragma once

#include <functional>
#include <memory>
#include <vector>

#include "flsh/contact/collider.h"
#include "flsh/sim/simulable.h"
#include "flsh/solve/hessian_assembler.h"
#include "flsh/solve/newton.h"

namespace flsh {

/// The Newton settings SceneOptions::soft_tissue_newton starts from (see there).
NewtonOptions softTissueNewtonDefaults();
/// The Newton settings SceneOptions::reduced_newton starts from (see there).
NewtonOptions reducedNewtonDefaults();

struct SceneOptions {
  /// Newton of skeleton-only scenes. newton.linear_solver = Auto gives the scene the simplicial
  /// sparse Cholesky (SparseLLT): its Hessian has a fixed block tree-sparse pattern (see
  /// Scene::hessian).
  NewtonOptions newton;
  /// Newton of scenes in which any simulable has soft tissue (hasSoftTissue()), used instead
  /// of `newton`. Defaults (softTissueNewtonDefaults()): the exact Hessian tried first at every
  /// iteration with the PSD form as fallback (exact_hessian = true; with the lag, negative
  /// curvature met by PCG switches that iteration to the PSD form, so an indefinite exact
  /// Hessian costs an assembly, not a failed 25 000-DoF factorization; the PSD form alone
  /// converges only linearly where it overestimates the curvature of compressed tissue: 7.1
  /// against 5.3 iterations per walking step), CHOLMOD's supernodal Cholesky
  /// (linear_solver = Cholmod; Auto also means Cholmod here) and the lagged-factor PCG
  /// (lagged.enabled = true: the factor of an earlier Hessian, kept by the scene's solver across
  /// steps, preconditions CG; see LaggedFactorOptions) with the forcing term
  /// lagged.cg_relative_tolerance = 5e-2 (walk: 0.80 factorizations and 36 PCG iterations per
  /// step against 1.13 and 39 at 1e-2, for the same Newton iterations, ~10 % faster), and
  /// gradient_tolerance = 1e-5: on the full-size walking body at h = 1/30 s it stays within
  /// 0.03 mm of a 1e-8 solve over 30 steps (displacements up to 29 mm), where 1e-4 ends 0.9 mm
  /// off for 8 % fewer iterations (docs/benchmarks.md). lagged.reuse_hessian_below = 1e-4: the
  /// last iterations' PCG may run on the previous iterate's Hessian (10 % fewer assemblies on
  /// the walk, same iterations, 0.0097 instead of 0.0070 mm from a 1e-8 solve).
  /// coarse_presolve.max_iterations = 8: each step's first iterations on the bones alone, the
  /// tissue held (CoarsePresolveOptions; walk 3.5 → 1.8 and jumping jacks 4.9 → 2.1 iterations
  /// on every DoF per step). The same in reduced_newton.
  NewtonOptions soft_tissue_newton = softTissueNewtonDefaults();
  /// Newton of scenes whose soft-tissue simulables all use the reduced model (ROM), used
  /// instead of `newton` and `soft_tissue_newton`. Defaults (reducedNewtonDefaults()): the exact
  /// Hessian (PSD fallback), gradient_tolerance 1e-6, the lagged-factor PCG, linear_solver =
  /// Auto, which here means the dense LLT up to 1500 DoFs (the handle block is dense: a few
  /// hundred DoFs per avatar) and CHOLMOD above. On the walking full body the PSD form at 1e-5
  /// ends 1.2 mm (10 % of the displacement) from a 1e-9 solve at the same speed where this ends
  /// 0.025 mm from it (docs/benchmarks.md). lagged.reuse_hessian_below = 1e-4: 12 % fewer
  /// Hessian assemblies on the walk for 1 % more iterations, the same distance from a 1e-9 solve.
  /// approximate_hessian = true: directions from the ROM's constant soft–soft block
  /// (Simulable::getApproximateHessianTripletVector) while they shrink the gradient fast, the
  /// exact form after (docs/rom.md "The approximate Hessian").
  NewtonOptions reduced_newton = reducedNewtonDefaults();
  /// Assemble the Hessian on the general pattern (HessianAssembler) even when no simulable has
  /// soft tissue. The skeleton then gets bitwise the same Hessians and states (its general
  /// pattern equals the block pattern) at some cost in speed: for tests and comparisons.
  bool general_hessian_pattern = false;
  /// In scenes with soft tissue, start each step's Newton from the lower-energy of the inertial
  /// prediction and the previous state (Simulable::setStepStart), for all simulables together.
  /// Where the tissue moves fast (feet pushed out of the ground, 5× motions, very soft tissue)
  /// the prediction can land deep in the Fung exponential (2.5e9 J against 241 J at the
  /// previous state in the stability sweep's ground case) and Newton's tolerance, relative to
  /// its first gradient, then accepts states with huge forces left (up to 1e23 N), which fling
  /// the tissue off within steps (docs/benchmarks.md, stability sweep). Costs two energy
  /// evaluations per step. Off: always the prediction (the former behaviour, and the skeleton's:
  /// its energies have no exponential, and the check cost it ~15 % of its speed).
  bool lower_energy_start = true;
  /// Vertices of each avatar against the other avatars' bone capsules.
  bool avatar_contact = true;
  ContactOptions avatar_contact_options;
};

/// What one Scene::step() did. `newton` is Newton's report: convergence, iterations, line-search
/// halvings, PSD fallbacks and regularizations, the final energy and ‖g‖∞; numeric
/// factorizations and PCG iterations (lagged factor) of the step; and where the step's time
/// went, in s: newton.seconds_energy (energies, line search included), seconds_gradient,
/// seconds_hessian (triplets and their assembly into the pattern), seconds_factorization
/// (numeric factorizations and symbolic analyses) and seconds_solve (back-substitutions and PCG).
/// What is left of `seconds` (preUpdate, postUpdate, Newton's own vector work) is the rest.
struct StepStats {
  NewtonResult newton;
  int active_contacts = 0;  ///< vertex–collider and vertex–capsule pairs in contact
  double seconds = 0.0;     ///< wall time of the step
};

class Scene : public Objective {
 public:
  explicit Scene(const SceneOptions& options = {});
  ~Scene() override;

  /// Adds an avatar (initialized or not); all simulables must share one time step.
  void addSimulable(std::shared_ptr<Simulable> simulable);
  /// Adds a collider seen by every avatar.
  void addCollider(const Collider& collider);
  /// Calls initialize() on every simulable.
  void initialize();
  /// One backward-Euler step of every simulable: preUpdate, Newton (newtonOptions()),
  /// postUpdate. A step that leaves some simulable with a non-finite state throws Error after
  /// restoring every simulable to its state before the step (saveStep / restoreStep).
  StepStats step();
  /// What a caller runs inside a step (either may be empty): after every preUpdate (e.g. to
  /// override the step's targets) and after Newton, before the postUpdates (e.g. to record the
  /// solved step, as the adjoint's Rollout does).
  struct StepHooks {
    std::function<void()> after_pre_update;
    std::function<void(const NewtonResult&)> before_post_update;
  };
  StepStats step(const StepHooks& hooks);
  /// True when some simulable has soft-tissue DoFs (numDofs() > numBoneDofs()).
  bool hasSoftTissue() const;
  /// True when some simulable has FEM soft tissue (soft-tissue DoFs, not the reduced model).
  bool hasFemSoftTissue() const;
  /// The Newton settings step() uses: options().newton for skeletons only, else
  /// options().soft_tissue_newton with FEM soft tissue, else options().reduced_newton.
  const NewtonOptions& newtonOptions() const;
  double time() const;
  void setStatic(bool on);

  const std::vector<std::shared_ptr<Simulable>>& simulables() const { return simulables_; }
  const std::vector<Collider>& colliders() const { return colliders_; }
  int offset(int i) const { return offsets_.at(i); }
  const SceneOptions& options() const { return options_; }
  LinearSolver* linearSolver() { return solver_.get(); }

  // Objective (the merged backward-Euler energy, including avatar–avatar contact)
  int numDofs() const override;
  double energy() override;
  void gradient(VecX& g) override;
  /// Both in one pass per simulable (Simulable::getEnergyAndGradientVector).
  bool energyAndGradient(double& energy, VecX& g) override;
  void hessian(SpMat& H, bool psd) override;
  /// The exact form with each simulable's approximation where it has one
  /// (Simulable::getApproximateHessianTripletVector: the ROM's constant soft–soft block); false
  /// (H untouched) when none has.
  bool approximateHessian(SpMat& H) override;
  void step(const VecX& dq) override;
  void push() override;
  void pop() override;
  bool discardPushed() override;
  void fixKinematic(VecX& g, SpMat* H) override;
  /// Every simulable's bone DoFs (6 per bone): the coarse level of the lagged-factor PCG and
  /// of Newton's coarse presolve.
  void coarseDofs(std::vector<int>& dofs) const override;
  /// Scenes with soft tissue: the bones' objective with the soft states held
  /// (Simulable::getBoneEnergyAndGradientVector, plus avatar–avatar contact), over coarseDofs();
  /// false for skeleton-only scenes (their whole objective is the bones'). In scene_bones.cpp.
  bool coarseEnergyAndGradient(double& energy, VecX& g) override;
  /// The bones' block of the Hessian (Simulable::getBoneHessianTripletVector and avatar–avatar
  /// contact), dense.
  void coarseHessian(MatX& H, bool psd) override;
  /// The presolve's sparse Cholesky, kept with its analysis of the bones' block pattern.
  LinearSolver* coarseSolver() override;

  /// Avatar–avatar contact energy at the current states; adds gradient/Hessian when asked.
  /// For every ordered pair (A, B) of different simulables, A's surface vertices x_i (areas
  /// a_i) against B's bone capsules moving with B's bones (a' = R_b(a − J_b) + t_b):
  /// Σ vertexCapsulePenalty(x_i, a', b', r, k·a_i). `g` (size numDofs()) is added to, `H`
  /// triplets (both triangles, merged indices) appended; psd = Gauss–Newton, else exact.
  /// Surface nodes x_i = Σ_b w_ib (R_b (Y_i − J_b) + t_b) with Y = getUnposedSurface() (the
  /// rest vertices for the skeleton). A vertex with soft-tissue DoFs u_i (nodeSoftDof(i) ≥ 0)
  /// also moves with them, ∂x_i/∂u_i = M_i = Σ_b w_ib R_b: its gradient gains M_iᵀ ∂E/∂x_i and
  /// its Hessian the u–u, u–(A's bones) and u–(B's capsule bone) blocks, plus in the exact form
  /// the rotation–displacement term of x_i's change w_ib [δω_b]× R_b δu_i.
  double avatarContactEnergy(VecX* g, std::vector<Triplet>* H, bool psd,
                             int* active = nullptr) const;

 private:
  struct AvatarContactData;
  AvatarContactData& contactData(int i) const;
  void poseCluster(int i, int cluster) const;  // skins one vertex cluster of simulable i
  void ensureSolver();
  bool avatarContactActive() const;

  SceneOptions options_;
  std::vector<std::shared_ptr<Simulable>> simulables_;
  std::vector<int> offsets_;
  std::vector<Collider> colliders_;
  std::unique_ptr<LinearSolver> solver_;
  std::unique_ptr<LinearSolver> coarse_solver_;  // the presolve's (scene_bones.cpp)
  int num_dofs_ = 0;
  int last_solver_dofs_ = -1;
  LinearSolverType solver_type_ = LinearSolverType::Auto;  // of solver_ (resolved)
  int stack_depth_ = 0;                                    // push() levels not yet popped
  std::vector<Triplet> triplets_;                          // Hessian assembly buffer, reused
  std::vector<FixedHessianBlocks> fixed_blocks_;  // the simulables' block lists, with triplets_
  // The bones' objective (scene_bones.cpp): the whole gradient's buffer, each DoF's coarse
  // index (−1: not a bone DoF), and the Hessian's triplets and lists.
  VecX bone_gradient_;
  std::vector<int> coarse_index_;
  std::vector<Triplet> bone_triplets_;
  std::vector<FixedHessianBlocks> bone_blocks_;
  void markKinematicBones(std::vector<char>& kinematic) const;
  // Fixed Hessian pattern of whole 6 × 6 bone blocks, a superset of every evaluation's
  // (all bone pairs that share a vertex, so collider contacts never change it): assembly
  // writes values in place and the solver keeps its analysis. block_rank_ (bones² entries):
  // position of block row a within block column b's stored blocks, −1 outside the pattern.
  SpMat hessian_pattern_;
  std::vector<int> block_rank_;
  // Value index in the pattern of each triplet position of the last assembly, with its
  // row · n + col key: the triplet order repeats between calls, so most lookups are skipped.
  mutable std::vector<long long> fill_key_;
  mutable std::vector<int> fill_index_;
  void rebuildHessianPattern();
  /// hessian() and approximateHessian() on the general pattern (HessianAssembler): every
  /// simulable's triplets and fixed blocks (its approximate form where `approximate` and it has
  /// one, else its exact or PSD form), then avatar–avatar contact.
  void assembleGeneral(SpMat& H, bool psd, bool approximate);
  bool fillHessian(SpMat& H) const;
  // General pattern (soft tissue, or SceneOptions::general_hessian_pattern): DoF groups of 6
  // per bone and 3 per soft-tissue node, and the couplings known in advance (as for the block
  // pattern: bone pairs sharing a vertex; with soft tissue also each surface node's u with its
  // bones), so that collider contacts never grow it. segment_end_: one triplet segment per
  // simulable and energy kind, then avatar–avatar contact.
  bool usesGeneralPattern() const;
  void setUpGeneralPattern();
  std::unique_ptr<HessianAssembler> general_;
  std::vector<size_t> segment_end_;
  // Per-simulable skinning data and the posed nodes/capsules of the last state seen.
  mutable std::vector<std::unique_ptr<AvatarContactData>> contact_data_;
  struct BlockAccumulator;
  mutable std::unique_ptr<BlockAccumulator> blocks_;
  mutable int avatar_contacts_ = 0;  // active vertex–capsule pairs at the last evaluation
  // Avatar–avatar pairs in contact, (capsule of B, vertex of A) per ordered pair A·n + B, found
  // at the posed-data versions contact_pairs_versions_ (one per simulable).
  mutable std::vector<std::vector<std::pair<int, int>>> contact_pairs_;
  mutable std::vector<long> contact_pairs_versions_;
};

}  // namespace flsh
