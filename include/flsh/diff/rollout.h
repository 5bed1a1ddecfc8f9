// Rollout: a differentiable simulation of one Simulable over T steps: the articulated skeleton,
// or the FEM or ROM soft skeleton (bones followed by the soft state in every state vector).
//
//   Rollout rollout(simulable, options);
//   rollout.run(T, inputs);                        // forward: simulate and record the tape
//   const RowMatX& q = rollout.states();           // T × numDofs state vectors
//   RolloutVariables grad = rollout.backward(dL_dq);      // reverse pass: dL/d(every input)
//   std::vector<RowMatX> dq = rollout.forwardSensitivities({direction, …});  // dq_t/dp · v
//
// Inputs (RolloutInputs; every empty member means "the simulable's own"): per-step pose targets
// (T × 72) and root translation targets (T × 3) overriding the mocap's after each preUpdate, the
// initial state and velocity, the 4 stiffnesses, a translation of every collider's path. The
// shape β, the rest joints and the bone inertias are the simulable's (β: its SoftAvatar; build
// a new avatar to change it); their gradients are reported too.
//
// Conventions of the gradients and directions (RolloutVariables), chosen so that they are with
// respect to the raw numbers a user passes (torch.autograd.gradcheck on them works):
//  - states: Simulable::getState layout, 6 per bone [t_b (m), rotation vector r_b (rad)]; a
//    cotangent dL/dq_t is with respect to those numbers (not the increment chart).
//  - initial_state: the same layout; initial_velocity: per DoF in the increment chart (m/s and
//    world-frame rad/s, Simulable::setVelocity).
//  - pose_targets: rotation vectors (rad), SMPL layout (bone b ≥ 1 relative to its parent, the
//    root global); root_targets: SMPL trans (m), the root joint's target being J_0(β) + trans.
//  - shape: β (K). Its gradient includes everything that moves with β in the simulation: rest
//    joints, bone inertias (SoftAvatar::boneInertiaShapeJacobian), the contact surface and its
//    vertex areas, and, when the initial state/velocity come from initialize(), their
//    dependence on J(β). Terms of a loss on SMPL vertices that depend on β directly come from
//    verticesCotangent() and are passed to backward() in `direct`.
//  - rest_joints (72) and bone_inertia (240): as if overridden by Simulable::setParameter before
//    the run (they are the pieces of the β chain; setParameter(RestJoints) moves the root target
//    J_0 + trans and, through initialize(), the initial state).
//  - material (soft tissue): MaterialModel::parameters() of the avatar's material file, a =
//    log c₀ and the log-slopes b of every coefficient (docs/materials.md): the gradient of a
//    rollout of SoftAvatar::withMaterial(model with these parameters). tissue_fraction and the
//    regions' tissue_scale select the bone nodes (kept by withMaterial): their gradient is 0.
// Soft tissue (FEM, ROM): every group. β also moves the rest nodes X̄(β), the node masses, the
// materials (c(β) and the tets' areas and volumes) and the contact areas: the gradient of
// shape is that of a rollout of SoftAvatar::withShape(β). The tet mesh, bone nodes, orthotropy
// frames and the ROM's basis, cubature and rest-split floors are part of the avatar's
// discretization, fixed during a rollout and by withMaterial / withShape: the gradient is exact
// for the model that is simulated. The vertices
// are the simulated surface (getVertices), which moves with the pose blend held from the
// previous state (VerticesCotangent::previous_state).
// Accuracy: the gradients are exact for the converged rollout; they are as accurate as Newton's
// convergence (RolloutOptions::newton.gradient_tolerance; use ~1e-10 or tighter when comparing
// with finite differences).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "flsh/diff/simulable_adjoint.h"
#include "flsh/diff/tape.h"
#include "flsh/sim/simulable.h"
#include "flsh/solve/newton.h"
#include "flsh/solve/scene.h"

namespace flsh {

/// Inputs of a rollout; empty members take the simulable's own values.
struct RolloutInputs {
  RowMatX pose_targets;   ///< T × 72 tracking targets per step (rad); empty = the mocap's
  RowMatX root_targets;   ///< T × 3 SMPL trans per step (m); empty = the mocap's
  VecX initial_state;     ///< numDofs (getState layout); empty = what initialize() sets
  VecX initial_velocity;  ///< numDofs (setVelocity layout); empty = what initialize() sets
  VecX stiffnesses;       ///< 4 (SimParameter::Stiffnesses); empty = the options at construction
  VecX collider_offsets;  ///< 3 per collider, added to its whole path (m); empty = zero
};

/// One value per rollout input group: gradients (backward) or directions (forward
/// sensitivities). In a direction, empty members are zero.
struct RolloutVariables {
  VecX shape;             ///< K
  VecX rest_joints;       ///< 72
  VecX bone_inertia;      ///< 240
  RowMatX pose_targets;   ///< T × 72
  RowMatX root_targets;   ///< T × 3
  VecX stiffnesses;       ///< 4
  VecX collider_offsets;  ///< 3 per collider
  /// Soft tissue: the material file's coefficients (MaterialModel::parameters(), 40 (1 + K)):
  /// as if the avatar were built with SoftAvatar::withMaterial. Empty for the skeleton.
  VecX material;
  VecX initial_state;     ///< numDofs
  VecX initial_velocity;  ///< numDofs

  /// The member holding registry group p (flsh/sim/sim_parameter.h): a one-per-rollout group's
  /// vector (perStep is null for it) or a per-step group's matrix (global is null).
  VecX* global(SimParameter p);
  RowMatX* perStep(SimParameter p);
  const VecX* global(SimParameter p) const;
  const RowMatX* perStep(SimParameter p) const;
};

/// Σ over groups of the element-wise products (empty members count as zero): vᵀ(dL/dp).
double dot(const RolloutVariables& a, const RolloutVariables& b);
/// into += add, group by group (empty members count as zero). Throws InputError when two
/// non-empty members differ in shape.
void accumulate(RolloutVariables& into, const RolloutVariables& add);

/// Newton's settings per model, as SceneOptions has them (a rollout's steps are its scene's).
/// The gradients are exact for the converged steps, so they are as accurate as these
/// tolerances: the soft models' defaults are the scene's with gradient_tolerance 1e-8.
struct RolloutOptions {
  NewtonOptions newton;  ///< the skeleton's (Auto: sparse Cholesky)
  NewtonOptions soft_tissue_newton = rolloutNewtonDefaults(softTissueNewtonDefaults());  ///< FEM
  NewtonOptions reduced_newton = rolloutNewtonDefaults(reducedNewtonDefaults());         ///< ROM
  /// What the tape keeps (tape.h, "Memory"): each step's factor, or only its snapshot (every
  /// sweep then factors each step again: memory grows with the state). Auto: the factors for
  /// the skeleton and the ROM (small), the snapshots for the FEM (a factor of the default
  /// resolution's exact Hessian is tens of MB: docs/benchmarks.md).
  enum class TapeStorage { Auto, Factors, Snapshots };
  TapeStorage tape_storage = TapeStorage::Auto;
  /// How the sweeps over snapshots solve with each step's exact Hessian (tape.h: by default
  /// PCG preconditioned by a nearby step's factor, for the FEM's large systems).
  TapeSolveOptions tape_solve;
  /// `scene_defaults` with gradient_tolerance 1e-8.
  static NewtonOptions rolloutNewtonDefaults(NewtonOptions scene_defaults) {
    scene_defaults.gradient_tolerance = 1e-8;
    return scene_defaults;
  }
};

class Rollout {
 public:
  /// Keeps the simulable (shared) and remembers its stiffnesses and colliders as the defaults
  /// of later runs. Throws InputError if null, Error if it has kinematic bones.
  explicit Rollout(std::shared_ptr<Simulable> simulable, const RolloutOptions& options = {});
  ~Rollout();

  /// Simulates `steps` steps from the inputs and records the tape: initialize(), the initial
  /// state/velocity, then per step preUpdate(), the target overrides, Newton, postUpdate(). The
  /// simulable is left after the last step. Throws InputError on wrong sizes or non-finite
  /// inputs (before changing anything), or on targets for a simulable that does not track.
  void run(int steps, const RolloutInputs& inputs = {});

  int numSteps() const;  ///< T of the last run (0 before)
  int numDofs() const;
  const RowMatX& states() const;     ///< T × numDofs, row t − 1 = state after step t
  const VecX& initialState() const;  ///< numDofs, q_0
  RowMatX joints() const;            ///< T × 72 joint (bone) positions t_b, m
  /// SMPL vertices (#V × 3, Simulable::getVertices) at step t (0 = initial state).
  MatX3 vertices(int t) const;
  /// The vertices of steps 1..T (T × 3#V, row t − 1: step t's #V × 3, row-major), as
  /// vertices(t) has them; the soft models' in one pass over the pose blend shapes and the soft
  /// basis (Simulable::getNodesOfFrames).
  RowMatX vertexTrajectory() const;
  const Tape& tape() const { return tape_; }
  Simulable& simulable() const { return model_.simulable(); }

  // ---- cotangent helpers (map a loss on outputs to dL/dq_t) ----------------------------
  /// dL/d(state vector) from dL/d(joint positions) (24 × 3): the t_b entries.
  VecX jointsCotangent(const MatX3& dL_djoints) const;
  struct VerticesCotangent {
    VecX state;  ///< dL/d(state vector at step t), numDofs
    /// Soft tissue: dL/d(state vector at step t − 1) (the pose blend held from it moves the
    /// surface; numDofs): add it to row t − 2 of dL/d(states), or for t = 1 to
    /// direct.initial_state (trajectoryCotangent does). Empty for the skeleton and for t = 0.
    VecX previous_state;
    /// The parts that do not go through the state: `shape` (K: SMPL shape and pose blend
    /// shapes and J_0(β) in trans = t_0 − J_0) and `rest_joints` (72: J_0 in trans). Pass them
    /// (summed over steps, see accumulate()) to backward() as `direct`.
    RolloutVariables direct;
  };
  /// dL/d(SMPL vertices at step t) (#V × 3) pulled back through getVertices (t = 1..T, or 0).
  VerticesCotangent verticesCotangent(int t, const MatX3& dL_dvertices) const;
  /// The arguments of backward() for a loss on whole trajectories: dL/d(joint positions)
  /// (T × 72, row t − 1: the 24 × 3 of step t, row-major) and dL/d(vertices) (T × 3#V, row
  /// t − 1: step t's #V × 3, row-major); either may be empty (zero).
  struct TrajectoryCotangent {
    RowMatX states;           ///< T × numDofs
    RolloutVariables direct;  ///< parts that do not go through the states
  };
  TrajectoryCotangent trajectoryCotangent(const RowMatX& dL_djoints,
                                          const RowMatX& dL_dvertices) const;

  // ---- derivatives ---------------------------------------------------------------------
  /// Reverse pass: dL/d(every input) for dL/dq_t (T × numDofs, state-vector layout), plus the
  /// loss's direct dependence on inputs (`direct`, e.g. VerticesCotangent::direct), added to
  /// the result. The simulable is left bitwise as it was. Throws InputError on wrong shapes /
  /// NaN, Error before run() or when a step did not converge (TapeStepInfo::converged).
  /// `groups`: the registry groups to compute (empty: all); the others come back empty and
  /// cost nothing (β and the soft models' Material are the expensive ones). The initial state
  /// and velocity are always computed.
  RolloutVariables backward(const RowMatX& dL_dstates, const RolloutVariables& direct = {},
                            const std::vector<SimParameter>& groups = {});
  /// Forward sensitivities: for each direction v, the T × numDofs changes of the state vectors
  /// dq_t/dp · v (one back-substitution per direction per step). `initial_states` (optional)
  /// receives each direction's change of q_0 (numDofs; e.g. for the soft surface of step 1,
  /// which moves with q_0 through the pose blend: VerticesCotangent::previous_state).
  std::vector<RowMatX> forwardSensitivities(const std::vector<RolloutVariables>& directions,
                                            std::vector<VecX>* initial_states = nullptr);

 private:
  void requireRun(const char* who) const;
  void requireConverged(const char* who) const;
  void checkVariables(const RolloutVariables& v, const std::string& who) const;
  /// trajectoryCotangent's vertex part for a soft-tissue simulable (adds into out).
  void softSurfaceCotangent(const RowMatX& dL_dvertices, TrajectoryCotangent& out) const;
  /// Soft tissue: the SurfaceFrame of steps 1..T (restores each; the step is kept).
  std::vector<SurfaceFrame> surfaceFrames() const;

  SimulableAdjointModel model_;
  std::shared_ptr<Simulable> simulable_;
  RolloutOptions options_;
  VecX base_stiffnesses_;
  std::vector<Collider> base_colliders_;
  Tape tape_;
  RowMatX states_;
  VecX initial_state_;
  bool state_from_initialize_ = true, velocity_from_initialize_ = true;
  MatX initial_state_joints_jacobian_, initial_velocity_joints_jacobian_;  // numDofs × 72
};

}  // namespace flsh
