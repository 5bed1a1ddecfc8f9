// Simulable: one avatar's simulation state and energies, with the runtime API of the FLSH paper.
//
// Backward Euler as an optimization (ARCHITECTURE.md §4):
//   q_{n+1} = argmin_q  E(q) = E_dyn(q) + E_pot(q),
//   E_dyn = 1/(2h²) Σ_mass points m ‖x(q) − x̂‖²,  x̂ = 2 x(q_n) − x(q_{n−1}),
//   E_pot = gravity + joint springs + tracking springs + contact (+ user terms).
//
// Articulated skeleton model: 24 rigid bones in maximal coordinates. Bone b has a world
// position t_b (where its joint centre is) and rotation R_b (relative to the rest T-pose), so a
// rest point X of the bone moves to x = R_b (X − J_b) + t_b; at rest t_b = J_b, R_b = I.
//
// State layout (getState/setState): 6 values per bone b, at 6b: [t_b (m, 3), r_b (rad, 3)]
// with r_b the rotation vector of R_b. Increments (updateState, gradients, Hessians) use the
// same 6 slots per bone: [δt_b, δω_b] with t_b ← t_b + δt_b and R_b ← exp([δω_b]×) R_b (a
// world-frame rotation increment). All derivatives are taken in this increment chart at the
// current state.
#pragma once

#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "flsh/body/motion.h"
#include "flsh/contact/collider.h"
#include "flsh/contact/contact_energy.h"
#include "flsh/core/hessian_blocks.h"
#include "flsh/core/types.h"
#include "flsh/sim/energy_term.h"
#include "flsh/sim/sim_parameter.h"
#include "flsh/sim/simulable_options.h"
#include "flsh/volume/soft_avatar.h"

namespace flsh {

/// Largest magnitude Simulable::setState accepts for a bone position or a soft-tissue value
/// (m), and the constructor for a mocap translation: 10 km. Rotation vectors are bounded by
/// kMaxRotationAngle (rotation.h).
constexpr double kMaxStatePosition = 1e4;
/// Largest magnitude Simulable::setVelocity accepts for any entry (m/s, rad/s): 10 km/s, far
/// beyond anything a body survives, and small enough that the energies stay finite.
constexpr double kMaxStateVelocity = 1e4;

// SimulableOptions (stiffnesses and physical settings): flsh/sim/simulable_options.h.

// SimParameter (the parameter groups): flsh/sim/sim_parameter.h.

/// What one step of a Simulable depends on besides its model data and parameter groups: the
/// current and previous states (rotations kept as matrices, so a restore is bitwise exact), the
/// time, the tracking targets and the colliders. Saved and restored by the adjoint's tape
/// (Simulable::saveStep / restoreStep).
struct SimulableStep {
  std::vector<Mat3> R, R_n, R_nm1;  ///< 24 bone rotations of q, q_n, q_{n−1}
  MatX3 t, t_n, t_nm1;              ///< 24 × 3 bone positions of q, q_n, q_{n−1}, m
  double time = 0.0;                ///< s
  std::vector<Mat3> target_R;       ///< 24 tracking targets (root: global)
  Vec3 target_t0 = Vec3::Zero();    ///< root position target, m
  std::vector<Collider> colliders;  ///< with their paths
  bool is_static = false;
  /// Soft tissue only (empty otherwise): displacements of q, q_n, q_{n−1} (3 per soft node, m)
  /// and the held pose blend: either its offsets (pose_blend, #N × 3, m) or, for the ROM, the 24
  /// rotations it comes from (pose_blend_R; the ROM evaluates a node's offset when first read, so
  /// its snapshots stay small and its steps never evaluate every node's). restoreStep uses
  /// pose_blend when it has rows, else pose_blend_R when given, else holds the blend from R_n as
  /// preUpdate does (e.g. after changing q_n in a snapshot).
  VecX u, u_n, u_nm1;
  MatX3 pose_blend;
  std::vector<Mat3> pose_blend_R;
  /// With pose_blend_R (the ROM): the offsets the step had evaluated, row k for node
  /// pose_blend_nodes[k] (m), restored as they are so that a reverse pass does not evaluate them
  /// again. They must come from pose_blend_R: clear both when changing it or R_n.
  std::vector<int> pose_blend_nodes;
  MatX3 pose_blend_rows;
};

/// What a soft-tissue surface (Simulable::getNodes) depends on at one state: the bones, the
/// rotations its pose blend is held from and the soft state. A rollout keeps one per step to
/// output or differentiate the surface of all its steps at once (Simulable::getNodesOfFrames).
struct SurfaceFrame {
  std::vector<Mat3> R;       ///< 24 bone rotations of q
  MatX3 t;                   ///< 24 × 3 bone positions of q, m
  std::vector<Mat3> held_R;  ///< the 24 rotations the pose blend is held from (q_n's)
  VecX soft;                 ///< the soft state of q (numDofs − numBoneDofs values)
};

/// Diagnostics of the last energy evaluation.
struct SimulableStats {
  int active_contacts = 0;
};

// FixedHessianBlocks, appendBlockTriplets: flsh/core/hessian_blocks.h.

/// Simulable::accumulateMaterialProducts' sums over steps.
struct SimulableMaterialProducts {
  MatX elements;       ///< per elastic element: C_world (36, column-major), μ, γ cotangents
  MatX rest_outer;     ///< ROM with the rest-stiffness split: Σ λ zᵀ (3H × 3H)
  VecX values;         ///< the node masses' share, in coefficient values
  bool shape = false;  ///< the sums also carry β's share (getGradientParameterVJPs with Shape)
};

class Simulable {
 public:
  /// `avatar` must be initialized (initVolumetricData()); `mocap` may be null (no tracking,
  /// the rest pose is the initial state). The paper's 3-argument form takes the body model
  /// explicitly; it must be the avatar's.
  Simulable(std::shared_ptr<const SoftAvatar> avatar, std::shared_ptr<const Motion> mocap = nullptr,
            const SimulableOptions& options = {});
  Simulable(std::shared_ptr<const SoftAvatar> avatar, std::shared_ptr<const BodyModel> body,
            std::shared_ptr<const Motion> mocap, const SimulableOptions& options = {});
  ~Simulable();
  Simulable(const Simulable&) = delete;
  Simulable& operator=(const Simulable&) = delete;

  /// Sets the state from the mocap's first frame (or the rest pose) with the mocap's initial
  /// velocity (zero without mocap); time = 0.
  void initialize();

  // ---- stepping --------------------------------------------------------------------------
  /// Before a step: advance time by h, update mocap targets (interpolated, slerp for
  /// rotations, when rates differ), set the inertial prediction x̂ from q_n and q_{n−1}, and
  /// move kinematic bones to their targets.
  void preUpdate();
  /// Where Newton starts the step set up by preUpdate: the inertial prediction (preUpdate's
  /// choice) or the previous state q_n, kinematic bones at their targets either way. Scene::step
  /// starts from whichever has the lower energy (SceneOptions::lower_energy_start).
  enum class StepStart { Prediction, PreviousState };
  void setStepStart(StepStart start);
  /// After the step converged: q_{n−1} ← q_n, q_n ← q.
  void postUpdate();

  // ---- state -----------------------------------------------------------------------------
  int numDofs() const;    ///< 6 · 24 (+ 3 per soft-tissue node)
  VecX getState() const;  ///< layout above
  /// Throws InputError on a wrong size, a non-finite value, a position or soft-tissue value
  /// beyond ±kMaxStatePosition or a rotation angle beyond kMaxRotationAngle.
  void setState(const VecX& q);
  void updateState(const VecX& dq);  ///< increment chart
  void pushState();                  ///< saves q on a stack
  void popState();                   ///< restores the last pushed q (throws if empty)
  /// Drops the last pushed q without restoring it (throws if empty): keeps an accepted trial
  /// state exactly, without a pop-and-reapply.
  void discardState();
  /// Sets the previous state so that the velocity (per DoF, m/s and rad/s in the world frame)
  /// is `v`: q_{n−1} = q_n − h v (in the increment chart). Throws InputError on a wrong size,
  /// a non-finite value or an entry beyond ±kMaxStateVelocity.
  void setVelocity(const VecX& v);
  VecX getVelocity() const;  ///< (q_n ⊖ q_{n−1}) / h
  double time() const;
  /// Snapshot of the step data (states, time, targets, colliders); restoreStep puts them back
  /// exactly (bitwise) and leaves the state stack alone. Throws InputError, restoring nothing,
  /// if the snapshot belongs to a simulable of another size or holds a NaN or Inf (states,
  /// time, targets, colliders, soft-tissue displacements and pose blend; the message names it).
  SimulableStep saveStep() const;
  void restoreStep(const SimulableStep& step);
  /// Derivatives of what initialize() sets with respect to the rest joints J (72 values, layout
  /// of SimParameter::RestJoints): the initial state, as increments (numDofs × 72; rotations do
  /// not depend on J), and the initial velocity (numDofs × 72). Either pointer may be null.
  /// (The initial state posed from the mocap's first frame moves with J, and with it the
  /// velocity from the first two frames.)
  void getInitialStateRestJointsJacobian(MatX* state_jacobian, MatX* velocity_jacobian) const;

  // ---- outputs and Jacobians ---------------------------------------------------------------
  /// SMPL pose (72, axis-angle per joint relative to its parent) and root translation read
  /// off the state: θ_b = log(R_pᵀ R_b), θ_0 = log(R_0), trans = t_0 − J_0.
  VecX getPose() const;
  Vec3 getTrans() const;
  /// d(θ, trans)/dq: 75 × numDofs (rows 0..71 pose, 72..74 trans).
  MatX getStateJacobian() const;
  /// Mesh vertices (#V × 3): SMPL skinning (with pose blend shapes) of getPose()/getTrans();
  /// with soft tissue, the simulated surface getNodes() (pose blend and displacements included).
  MatX3 getVertices() const;
  /// Simulation nodes on the surface (#V × 3), used by contact: linear blend skinning of the
  /// unposed surface, x_i = Σ_b w_ib (R_b (Y_i − J_b) + t_b) (Y = getUnposedSurface()).
  MatX3 getNodes() const;
  /// d(nodes)/dq: 3#V × numDofs, sparse.
  SpMat getNodesStateJacobian() const;
  /// Cotangents of a loss on getNodes() (dL/dnodes, #V × 3): the state's (getNodesStateJacobian
  /// transposed times dL/dnodes, without forming the matrix; numDofs, increments), the previous
  /// state q_n's (numDofs, its increments: with soft tissue the nodes move with the pose blend
  /// held from q_n's rotations; zero for the skeleton) and the rest joints' (72:
  /// x_i = Σ_b w_ib (R_b (Y_i − J_b) + t_b)). `rest_nodes_shape` (K, soft tissue only; zero for
  /// the skeleton): β's share through the rest nodes Y_i ∋ X̄_i(β), without the rest joints'
  /// (chain those with chainShapeCotangent). Any pointer may be null. Throws InputError on a
  /// wrong shape. Does not change the state.
  void getNodesCotangents(const MatX3& dL_dnodes, VecX* state, VecX* previous_state,
                          VecX* rest_joints, VecX* rest_nodes_shape = nullptr) const;
  /// Soft tissue: the current state's SurfaceFrame. Throws InputError without soft tissue.
  SurfaceFrame getSurfaceFrame() const;
  /// getNodes of many frames at once (soft tissue): row k (3#V, row-major: 3i + c) the surface
  /// of frames[k]. The pose blend shapes and the soft basis of every surface node are read
  /// once for all frames (two matrix products), not once per frame. Throws InputError on a
  /// frame of the wrong sizes or without soft tissue.
  RowMatX getNodesOfFrames(const std::vector<SurfaceFrame>& frames) const;
  /// getNodesCotangents of many frames at once (soft tissue; Rollout::trajectoryCotangent): row
  /// k of dL_dnodes (3#V, row-major) is a loss's cotangent of frames[k]'s surface; row k of
  /// `state` and `previous_state` (#frames × numDofs, increments) is that frame's state and
  /// previous_state; `rest_joints` (72) and `rest_nodes_shape` (K) are summed over the frames.
  /// Any pointer may be null. Throws InputError on wrong shapes or without soft tissue.
  void getNodesCotangentsOfFrames(const std::vector<SurfaceFrame>& frames, const RowMatX& dL_dnodes,
                                  RowMatX* state, RowMatX* previous_state, VecX* rest_joints,
                                  VecX* rest_nodes_shape) const;

  /// Current bone transforms: rotations R_b (24) and joint positions t_b (24 × 3).
  const std::vector<Mat3>& boneRotations() const;
  const MatX3& bonePositions() const;

  // ---- soft tissue (FEM soft skeleton, docs/fem.md) ------------------------------------------
  // With SoftAvatar::enableSoftTissue() the state is the 24 bones (6 values each, as above)
  // followed by one displacement u_j (3 values, m, in the unposed space) per soft-tissue node of
  // the avatar's tet mesh, in softNodes() order. A tet node j (bone node or not) is at
  //   x_j = Σ_b w_jb (R_b (Y_j − J_b) + t_b),  Y_j = X̄_j(β) + P_j(θ_n) + u_j,
  // with P_j the pose blend offsets at the pose of the last converged state (held during a
  // step) and u_j = 0 on bone nodes. The surface vertices are tet nodes 0..V−1.
  // With SoftAvatar::enableReducedModel() too (the ROM, docs/rom.md) the bones are followed by
  // one z_h (3 values, m) per handle of the avatar's reduced basis instead, and
  // u_j = Σ_h φ_h(j) z_h (bounded biharmonic weights φ; at a handle u = z_h).
  bool hasSoftTissue() const;
  bool hasReducedModel() const;  ///< the ROM (a soft-tissue model with the reduced basis)
  int numBoneDofs() const;       ///< 6 · 24
  /// The tet node of each 3-value block of the soft state, in state order ((numDofs −
  /// numBoneDofs) / 3 entries): every soft-tissue node (FEM) or the handles (ROM); empty for the
  /// skeleton model.
  const VecXi& softNodes() const;
  /// State index of tet node j's first displacement value when u_j is a state entry of its own,
  /// else −1: bone nodes, every vertex of the skeleton model, and in the ROM every node but the
  /// handles (use nodeDisplacementBasis). Throws InputError for j outside the nodes.
  int nodeSoftDof(int j) const;
  /// u_j as a combination of state entries: u_j = Σ block · q.segment<3>(index) over the
  /// returned (index, 3 × 3 block) pairs; empty for bone nodes and the skeleton model. FEM: one
  /// pair (nodeSoftDof(j), I); ROM: (index of z_h, φ_h(j) I) for the handles whose φ reaches j,
  /// then with modes (ReducedBasisKind) one pair per three modal coordinates, the block Ψ_j's
  /// three columns. Throws InputError for j outside the nodes.
  std::vector<std::pair<int, Mat3>> nodeDisplacementBasis(int j) const;
  /// Soft-tissue displacements u of the surface vertices (#V × 3, m, unposed space); zero on
  /// bone nodes and for the skeleton model.
  MatX3 getSoftTissueDisplacements() const;
  /// Unposed surface Y_i (#V × 3, m): the rest surface X̄(β), plus for the soft-tissue model the
  /// held pose blend offsets and u_i. Contact and skinning of the surface read it.
  MatX3 getUnposedSurface() const;
  /// World positions of every tet node (#N × 3, m); the skeleton model: the surface vertices.
  MatX3 getVolumeNodes() const;

  // ---- energies (values at the current state) ------------------------------------------------
  double getDynamicEnergyScalar() const;
  double getPotentialEnergyScalar() const;
  /// Gradients are ADDED into g at `offset` (g must be large enough).
  void getDynamicGradientVector(VecX& g, int offset = 0) const;
  void getPotentialGradientVector(VecX& g, int offset = 0) const;
  /// Both gradients at once (their sum ADDED at offset), as a scene sums them. The ROM evaluates
  /// its node terms (inertia and gravity) beside contact on two OpenMP threads, the elastic
  /// tets split between them: the same sum up to round-off.
  void getGradientVector(VecX& g, int offset = 0) const;
  /// getGradientVector and, from the same passes, the whole energy (getDynamicEnergyScalar() +
  /// getPotentialEnergyScalar(), up to round-off) as the result: every term's gradient pass also
  /// gives its energy, so this costs about what the gradient alone does. Newton's line search
  /// asks it at trial states (Scene::energyAndGradient), whose gradient it needs next when the
  /// trial is accepted.
  double getEnergyAndGradientVector(VecX& g, int offset = 0) const;
  /// Zeroes the entries of kinematic DoFs.
  void fixVectorKinematic(VecX& g, int offset = 0) const;
  /// Hessian triplets are APPENDED (both triangles) with indices shifted by `offset`. `psd`:
  /// the positive-semidefinite form Newton uses (projected terms); false: the exact Hessian.
  /// (Inertia: `psd` gives Gauss–Newton, Σ m JᵀJ; false adds the residual curvature.)
  void getDynamicHessianTripletVector(std::vector<Triplet>& H, int offset = 0,
                                      bool psd = true) const;
  void getPotentialHessianTripletVector(std::vector<Triplet>& H, int offset = 0,
                                        bool psd = true) const;
  /// The same Hessians with the blocks of fixed position (FEM: the elastic node pairs, and the
  /// bone–tissue coupling and node-diagonal blocks of inertia and gravity; ROM: every bone–handle
  /// and handle–handle block, one list per part) returned as lists APPENDED to `blocks` instead
  /// of as triplets (for assemblers that cache their slots, e.g. Scene's; triplets plus blocks
  /// sum to the triplet version's Hessian). Each call appends the same number of lists with the
  /// same positions for a given simulable (none for the skeleton). A list's values are valid
  /// until the next Hessian call of that part.
  void getDynamicHessianTripletVector(std::vector<Triplet>& H,
                                      std::vector<FixedHessianBlocks>& blocks, int offset,
                                      bool psd) const;
  void getPotentialHessianTripletVector(std::vector<Triplet>& H,
                                        std::vector<FixedHessianBlocks>& blocks, int offset,
                                        bool psd) const;
  /// Both parts at once, as a scene assembles them: the triplets and lists of the dynamic
  /// block overload followed by those of the potential one (same values, same order). Returns
  /// the index in H where the potential part's triplets start. The ROM evaluates its inertia
  /// concurrently with contact, gravity and elasticity here (two OpenMP threads, a tenth of
  /// inertia's mass nodes with the potential terms to balance them): its two parts then differ
  /// from the separate overloads' (that share of inertia's blocks comes in the potential part's
  /// triplets and list, in another order) while their sum is the same up to round-off.
  size_t getHessianTripletVector(std::vector<Triplet>& H, std::vector<FixedHessianBlocks>& blocks,
                                 int offset, bool psd) const;
  /// The energy and gradient of the terms that move with the bones: every term but the soft
  /// tissue's elasticity (EnergyTerm::dependsOnBones), which reads the soft state alone. With the
  /// soft state held they are the bones' objective up to a constant, for Newton's coarse
  /// presolve (Scene::coarseEnergyAndGradient). The gradient's bone entries are ADDED into g
  /// (numDofs at offset) and equal getGradientVector's; its soft-state entries may be left out
  /// (the node terms skip their chain rule to the soft state). Without soft tissue: every term.
  double getBoneEnergyAndGradientVector(VecX& g, int offset = 0) const;
  /// Those terms' Hessian, appended as getHessianTripletVector appends (triplets, then lists):
  /// its bone–bone block equals the whole Hessian's.
  void getBoneHessianTripletVector(std::vector<Triplet>& H, std::vector<FixedHessianBlocks>& blocks,
                                   int offset, bool psd) const;
  /// A cheaper approximation of getHessianTripletVector's exact form in the same layout, for
  /// Newton's directions (Objective::approximateHessian): the ROM with the rest-stiffness split
  /// takes its soft–soft block as the constant K_r + Σ_j (m_j / h²) B_jᵀ B_j (the subspace's
  /// exact rest stiffness and the mass-node Gram of the basis: exact where M_jᵀ M_j = I, i.e.
  /// for the nodes one bone moves, and at rest) instead of the elastic tets' and inertia's
  /// soft–soft blocks; the bones, their coupling to the soft state, gravity and contact stay
  /// exact. Returns false (nothing appended) for models without one (skeleton, FEM, a ROM
  /// without the split, a static simulable); else the index where the potential part starts.
  bool hasApproximateHessian() const;
  bool getApproximateHessianTripletVector(std::vector<Triplet>& H,
                                          std::vector<FixedHessianBlocks>& blocks, int offset,
                                          size_t* potential_start = nullptr) const;
  /// Makes kinematic rows/columns of the assembled H identity (drops their triplets and adds
  /// unit diagonals): call on the full triplet list before assembly.
  void fixMatrixKinematic(std::vector<Triplet>& H, int offset = 0) const;

  // ---- scene hooks -------------------------------------------------------------------------
  void setColliders(std::vector<Collider> colliders);
  const std::vector<Collider>& colliders() const;
  /// Turns the dynamic term off (static equilibrium problems).
  void setStatic(bool on);
  bool isStatic() const;

  const SoftAvatar& avatar() const;
  /// The mocap the simulable tracks (null without one).
  std::shared_ptr<const Motion> mocap() const;
  const SimulableOptions& options() const;
  /// The Material group's products over many steps (a reverse sweep, SimulableAdjointModel):
  /// accumulateMaterialProducts ADDS step by step what Σ_t (∂g_t/∂p_material)ᵀ λ_t needs —
  /// each elastic element's material-point cotangent, the ROM's Σ λ zᵀ of its exact rest
  /// stiffness, the node masses' share — and finishMaterialProducts chains the sum once
  /// (parameterSize(Material) values): one pass over the tets and their material map per sweep
  /// instead of one per step. Error without soft tissue.
  using MaterialProducts = SimulableMaterialProducts;
  void accumulateMaterialProducts(const VecX& lambda, MaterialProducts& sum) const;
  /// `shape` (may be null): β's share of the sums (K; zero unless the sums were taken with the
  /// Shape group, SimulableMaterialProducts::shape), to add to the steps' Shape products.
  VecX finishMaterialProducts(const MaterialProducts& sum, VecX* shape = nullptr) const;
  /// ROM with the elastic cubature's rest-stiffness split: how many sample tets' excess is in
  /// its bounded branch (f_e = −q h(x), the floor acting) at the current state; 0 for other
  /// models. A diagnostic of the cubature (one energy pass over its samples).
  int restSplitBoundedSamples() const;
  SimulableStats stats() const;

  // ---- parameter derivatives (for the adjoint) ---------------------------------------------
  /// Number of values of a parameter group (ColliderOffsets: 3 per current collider; Shape: K).
  int parameterSize(SimParameter p) const;
  /// Current values of a parameter group (layout of SimParameter).
  VecX getParameter(SimParameter p) const;
  /// Overrides a parameter group (e.g. for optimization or finite differences); the state is
  /// kept. PoseTargets and RootTranslationTarget hold until the next preUpdate()/initialize()
  /// recomputes them from the mocap; ColliderOffsets shifts each collider's whole path.
  /// Throws InputError on size / non-finite / invalid values.
  void setParameter(SimParameter p, const VecX& value);
  /// ∂g/∂p of the total gradient g = ∇(E_dyn + E_pot) at the current state (exact, increment
  /// chart, kinematic rows not zeroed): numDofs × parameterSize(p). Does not change the state.
  MatX getGradientParameterJacobian(SimParameter p) const;
  /// The same for several groups at once, sharing the work they have in common (Shape chains
  /// RestJoints and BoneInertia): one matrix per entry of `groups`, in order.
  /// `shape_surface_only`: as for getGradientParameterVJPs below.
  std::vector<MatX> getGradientParameterJacobians(const std::vector<SimParameter>& groups,
                                                  bool shape_surface_only = false) const;
  /// ∂g/∂q_n (which = 1) or ∂g/∂q_{n−1} (which = 2): numDofs × numDofs, with respect to
  /// increments of that previous state in the same chart. The articulated skeleton: the inertia
  /// term alone (zero when static). Soft tissue: the nodal inertia's prediction x̂ (bones and
  /// soft state of both), and the pose blend offsets held from q_n's rotations, which move the
  /// nodes of inertia, gravity and contact (also when static); formed from numDofs tangents
  /// (small models and tests; the adjoint uses the products below). Does not change the state.
  MatX getGradientPreviousStateJacobian(int which) const;
  /// Vector–Jacobian products (∂g/∂p)ᵀ λ for several groups (λ: numDofs), one vector of
  /// parameterSize(p) per entry of `groups`, without forming the matrices (the adjoint's reverse
  /// sweep). `shape_surface_only`: the Shape entry holds only the contact-surface part (X(β),
  /// a(β)); the caller chains the RestJoints and BoneInertia products with
  /// SoftAvatar::restJointsShapeJacobian / boneInertiaShapeJacobian itself (e.g. once per
  /// rollout). Throws InputError on a wrong size of λ. Does not change the state.
  /// `material_sum` (soft tissue, may be null): the Material products are accumulated into it
  /// (accumulateMaterialProducts) and the Material entry comes back zero; with Shape, β's share
  /// through the materials (and the ROM's every tet of K) too, finishMaterialProducts' `shape`.
  std::vector<VecX> getGradientParameterVJPs(const VecX& lambda,
                                             const std::vector<SimParameter>& groups,
                                             bool shape_surface_only = false,
                                             MaterialProducts* material_sum = nullptr) const;
  /// Jacobian–vector products Σ_p ∂g/∂p ṗ_p for several directions at once (each: one pointer
  /// per group, indexed by SimParameter; null or empty = no change), one numDofs vector per
  /// direction, without forming the matrices (the forward sensitivities' tangent sweep). A Shape
  /// direction includes the rest joints' and bone inertias' change with β unless
  /// `shape_surface_only`. Throws InputError on a wrongly sized direction. Does not change the
  /// state.
  std::vector<VecX> getGradientParameterJVPs(const std::vector<ParameterDirection>& directions,
                                             bool shape_surface_only = false) const;
  /// (∂g/∂q_n)ᵀ λ and (∂g/∂q_{n−1})ᵀ λ (numDofs each; either pointer may be null), and the
  /// tangent ∂g/∂q_n dq_n + ∂g/∂q_{n−1} dq_{n−1}, without forming the matrices (the skeleton:
  /// per-bone 6 × 6 inertia blocks; soft tissue: per node, and the held pose blend's chain).
  void getGradientPreviousStatesVJP(const VecX& lambda, VecX* a_n, VecX* a_nm1) const;
  VecX getGradientPreviousStatesJVP(const VecX& dq_n, const VecX& dq_nm1) const;

  // ---- energy terms (energy_term.h) ---------------------------------------------------------
  /// The terms whose sum is the articulated skeleton's energy: rigid inertia (the dynamic part),
  /// bone gravity, joint springs, tracking and root springs, collider contact. With soft tissue
  /// (FEM or ROM): the bones' joint and tracking springs, then the node terms — nodal inertia,
  /// nodal gravity, elasticity, node contact — that read the soft kinematics (β's share through
  /// the rest nodes and the elastic rest shapes is added by the simulable's parameter
  /// derivatives, not by the terms' own products). Owned by the simulable.
  std::vector<const EnergyTerm*> energyTerms() const;
  /// The view the terms read at the current state, with contact (and the soft kinematics) up to
  /// date. Its references
  /// are the simulable's: valid until the state, a parameter or the colliders change.
  TermContext termContext() const;

  struct Impl;

 private:
  /// Both overloads of getDynamicHessianTripletVector / getPotentialHessianTripletVector
  /// (blocks null: every term as triplets).
  /// bones_only: the terms that depend on the bones alone (getBoneHessianTripletVector).
  void dynamicHessian(std::vector<Triplet>& H, std::vector<FixedHessianBlocks>* blocks, int offset,
                      bool psd, bool bones_only = false) const;
  /// soft_done (ROM): gravity's, the elastic term's and contact's Hessians are already summed
  /// (the ROM's value list; their bone triplets are the caller's to append).
  void potentialHessian(std::vector<Triplet>& H, std::vector<FixedHessianBlocks>* blocks,
                        int offset, bool psd, bool soft_done = false,
                        bool bones_only = false) const;
  /// ROM: appends the two-thread schedule's Hessian (in the scratch lists and value lists) and
  /// the bones' springs; returns where the potential part starts.
  size_t appendScheduledHessian(std::vector<Triplet>& H, std::vector<FixedHessianBlocks>& blocks,
                                int offset, bool psd) const;
  /// The bones' springs (and, without soft tissue, the bones' gravity): gradient added, energy
  /// returned.
  double boneSpringGradient(VecX& g, int offset) const;
  /// getDynamicGradientVector / getPotentialGradientVector, returning the energy their passes
  /// give.
  double dynamicGradient(VecX& g, int offset) const;
  double potentialGradient(VecX& g, int offset) const;
  std::unique_ptr<Impl> impl_;
};

}  // namespace flsh
