// The kinematics of the soft skeletons (ARCHITECTURE.md §4), private to Simulable: the map from
// the state q = (bones, soft state) to the tet nodes' world positions, and the chain rule that
// takes node derivatives back to q. The node terms (nodal inertia, gravity, elasticity, contact)
// read positions here and hand their node forces and 3 × 3 node Hessians to mapForces /
// mapHessian; they never see which soft state the model has.
//
// Node j of the tet mesh is at x_j = Σ_b w_jb (R_b (Y_j − J_b) + t_b), Y_j = X̄_j + P_j + u_j
// (rest node, held pose blend offset, displacement; u = 0 on bone nodes). Its derivatives in the
// increment chart (δt_b, δω_b, δu_j):
//   ∂x_j/∂δt_b = w_jb I,  ∂x_j/∂δω_b = −w_jb [r_jb]×  with r_jb = R_b (Y_j − J_b),
//   ∂x_j/∂δu_j = M_j = Σ_b w_jb R_b.
// Second derivatives: ∂²(f·x_j)/∂δω_b² = w_jb (½(f r_jbᵀ + r_jb fᵀ) − (f·r_jb) I) and
// ∂²(f·x_j)/∂δω_b∂δu_j = −w_jb [f]× R_b.
//
// Two soft states: the FEM's (u of every soft-tissue node, 3 values each) and the ROM's
// (SoftAvatar::enableReducedModel: z, 3 per handle, then one per mode, u_j = Σ_h φ_h(j) z_h +
// Ψ_j z_modes with the avatar's basis kind, ReducedBasisKind), so every u-derivative maps to z by
// the chain rule. The ROM's state comes in groups of three entries: each handle's z_h, then the
// modal coordinates three by three; node j's displacement is u_j = Σ_g B_jg z_g over the groups g
// with B_jg = φ_g(j) I for a handle and the 3 × 3 block of Ψ_j's columns of g for modes, so that
// ∂/∂z_g = Σ_j B_jgᵀ ∂/∂u_j and Hessian blocks (i, j) go to (g, k) as B_igᵀ · B_jk. The FEM's
// Hessian blocks go out as triplets (or fixed blocks); the ROM's are summed at fixed positions into
// one of two value lists (0: the dynamic Hessian, 1: the potential one) and handed over by
// flushList. Only the nodes some term reads are skinned per evaluation: the evaluated nodes (all in
// the FEM, the mass nodes in the ROM) and the surface nodes contact or output ask for; in the ROM a
// node's pose blend offset is evaluated when first read.
#pragma once

#include <utility>
#include <vector>

#include "flsh/core/hessian_blocks.h"
#include "flsh/core/types.h"
#include "flsh/volume/soft_avatar.h"
#include "sim/block_hessian_term.h"
#include "sim/hessian_blocks.h"
#include "sim/model_kinematics.h"

namespace flsh::detail {

struct SkinnedPoint;

class SoftKinematics final : public HessianValueLists, public ModelKinematics {
 public:
  struct Influence {
    int bone;
    double weight;
  };

  /// Reads the avatar's volumetric data (soft tissue on, initialized). `joints`: 24 × 3 rest
  /// joints J(β) (the simulable's).
  SoftKinematics(const SoftAvatar& avatar, const MatX3& joints, const std::vector<int>& parents);

  /// Sets the nodes that carry mass (read by every evaluation): the ROM skins only these in
  /// prepare() and keeps their pose blend rows; the FEM lays out the fixed positions of their
  /// bone–tissue coupling blocks (couplingPositions). Call once, before buildReducedPattern.
  void setMassNodes(const std::vector<int>& nodes);
  /// ROM: the fixed positions of every Hessian block: group pairs some node's basis row couples
  /// (every pair of modal groups, and those with the handles of every soft node), plus
  /// `handle_pairs` (elastic tets, the rest stiffness: groups), and bone–group pairs some node's
  /// skinning couples. No-op for the FEM.
  void buildReducedPattern(const std::vector<std::pair<int, int>>& handle_pairs);

  // ---- layout ----
  int numBones() const { return num_bones_; }
  int boneDofs() const { return bone_dofs_; }
  int numNodes() const { return int(rest_.rows()); }
  int numSurface() const override { return num_surface_; }
  bool reduced() const { return reduced_; }
  int numHandles() const { return num_handles_; }
  int numModes() const { return num_modes_; }
  /// ROM: groups of three soft-state entries: the handles, then the modes three by three.
  int numGroups() const { return num_groups_; }
  int numSoftDofs() const override { return 3 * int(state_nodes_.size()) + num_modes_; }
  const VecXi& softNodes() const { return state_nodes_; }
  /// FEM: offset of u_j in the soft state (−1 on bone nodes); ROM: the handle's z offset at a
  /// handle node, −1 elsewhere.
  int nodeDof(int j) const { return reduced_ ? state_dof_[j] : node_dof_[j]; }
  /// Whether node j moves with the soft state (a soft-tissue node, not a bone node).
  bool isSoftNode(int j) const { return node_dof_[j] >= 0; }
  const MatX3& restNodes() const { return rest_; }
  const MatX3& joints() const { return joints_; }
  /// New rest joints J (24 × 3, m; Simulable::setParameter(RestJoints)): the next prepare()
  /// skins again.
  void setJoints(const MatX3& joints) {
    joints_ = joints;
    version_ = -1;
  }
  /// ROM: node j's handle weights as (handle, φ) pairs, sorted by handle (its modal rows:
  /// modeRows).
  const std::pair<int, double>* basisBegin(int j) const { return phi_.data() + phi_start_[j]; }
  const std::pair<int, double>* basisEnd(int j) const { return phi_.data() + phi_start_[j + 1]; }
  /// ROM: the handles whose basis reaches any of a tet's four nodes, ascending, into `handles`.
  void tetHandles(const Eigen::Vector4i& nodes, std::vector<int>& handles) const;
  /// ROM with modes: Ψ_j, node j's 3 × r rows of the modes (zero on bone nodes).
  Eigen::Map<const Eigen::Matrix<double, 3, Eigen::Dynamic, Eigen::RowMajor>> modeRows(
      int j) const {
    return {modes_.data() + size_t(3) * size_t(num_modes_) * size_t(j), 3, num_modes_};
  }
  /// ROM with modes: every node's Ψ_j stacked (3·#nodes × r, node j's rows 3j .. 3j + 2).
  const RowMatX& allModeRows() const { return modes_; }
  /// Skinning influences of node j.
  const Influence* influencesBegin(int j) const { return influences_.data() + influence_start_[j]; }
  const Influence* influencesEnd(int j) const {
    return influences_.data() + influence_start_[j + 1];
  }

  // ---- state (the bones live in Simulable) ----
  VecX u, u_n, u_nm1;  ///< 3 · #soft nodes (FEM, u, m) or 3 · #handles + #modes (ROM, z)

  /// u_j for a soft state (m, unposed space; zero on bone nodes).
  Vec3 nodeDisplacement(const VecX& state, int j) const {
    if (!reduced_) return node_dof_[j] < 0 ? Vec3::Zero() : Vec3(state.segment<3>(node_dof_[j]));
    Vec3 d = handleDisplacement(state, j);
    if (num_modes_ > 0 && node_dof_[j] >= 0) d += modalDisplacement(state, j);
    return d;
  }
  /// Σ_h φ_h(j) z_h (ROM): the handles' part of u_j.
  Vec3 handleDisplacement(const VecX& state, int j) const {
    Vec3 d = Vec3::Zero();
    for (int k = phi_start_[j]; k < phi_start_[j + 1]; ++k)
      d += phi_[k].second * state.segment<3>(3 * phi_[k].first);
    return d;
  }
  /// Ψ_j z_modes (ROM with modes): three dot products of Ψ_j's contiguous rows.
  Vec3 modalDisplacement(const VecX& state, int j) const {
    const double* row = modes_.data() + size_t(3) * size_t(num_modes_) * size_t(j);
    const Eigen::Map<const VecX> z(state.data() + 3 * num_handles_, num_modes_);
    return {Eigen::Map<const VecX>(row, num_modes_).dot(z),
            Eigen::Map<const VecX>(row + num_modes_, num_modes_).dot(z),
            Eigen::Map<const VecX>(row + 2 * num_modes_, num_modes_).dot(z)};
  }
  /// ∂u_j/∂(soft state) as (state offset, 3 × 3 block) pairs: u_j = Σ block ·
  /// state.segment<3>(offset) (FEM: the identity at u_j's entries; ROM: φ_h(j) I per handle,
  /// then Ψ_j's blocks of three columns).
  void displacementBasis(int j, std::vector<std::pair<int, Mat3>>& out) const;
  /// Σ of node i's handle weights φ_h(i) (1 or 0 in the FEM),
  /// for the contact broad phase: ‖u_i‖ ≤ displacementWeight(i) · largestSoftState() +
  /// modeNorm(i) · ‖z_modes‖₂.
  double displacementWeight(int i) const;
  /// ‖Ψ_i‖_F (ROM with modes; 0 otherwise): ‖Ψ_i z_modes‖ ≤ modeNorm(i) ‖z_modes‖₂.
  double modeNorm(int i) const;
  /// max over the 3-blocks of the soft state of ‖·‖ (ROM: the handles' blocks), m
  double largestSoftState() const;
  /// Sets the surface nodes each bone dominates (SkinnedSurface::dominated) for contactMargins:
  /// per bone the largest blendBound and displacementWeight of its nodes.
  void setContactBones(const std::vector<std::vector<int>>& dominated);
  /// Per bone: max blendBound · poseFeatureNorm() + max displacementWeight ·
  /// largestSoftState() + max modeNorm · ‖z_modes‖₂ over the surface nodes it dominates
  /// (≥ ‖Y_i − X̄_i‖ there).
  void contactMargins(double* margin) const override;
  /// ROM with modes: x̃_i skins node i without Ψ_i z_modes, s_i = Σ_k |w_ik| · modeNorm(i) ·
  /// ‖z_modes‖₂ (≥ ‖M_i Ψ_i z_modes‖). Skinning a candidate through Ψ_i reads 3r values, x̃_i a
  /// few: on the walk with the ground, ~680 candidates of the broad phase become ~8.
  void pruneCandidates(const std::function<double(const Vec3&)>& distance,
                       std::vector<int>& candidates) const override;

  // ---- pose blend ----
  /// Held pose blend offsets P (#N × 3, m) from the bones' rotations (relative rotations
  /// R_pᵀ R_b give the pose feature). The FEM evaluates every node's; the ROM keeps the feature
  /// and evaluates a node's offset when first read.
  void setPoseBlend(const std::vector<Mat3>& R);
  const MatX3& poseBlend() const;  ///< every node's (evaluates the missing ones)
  void setPoseBlendOffsets(const MatX3& offsets);
  /// ROM: the rotations the held pose blend was set from by setPoseBlend (null after
  /// setPoseBlendOffsets, and always for the FEM, which holds every node's offsets).
  const std::vector<Mat3>* heldPoseRotations() const {
    return reduced_ && from_feature_ ? &held_R_ : nullptr;
  }
  /// ROM, a blend held from rotations: the nodes whose offsets have been evaluated (ascending)
  /// and their offsets (rows of `offsets`); empty otherwise.
  void evaluatedPoseBlend(std::vector<int>& nodes, MatX3& offsets) const;
  /// ROM, right after setPoseBlend(R) with the rotations such rows were evaluated from: takes
  /// them as evaluated (a reverse pass's restored step then reads them instead of posedirs).
  void seedPoseBlend(const std::vector<int>& nodes, const MatX3& offsets);
  /// Derivatives of the pose blend offsets P_j = posedirs_j · feature(R) in the rotations R it
  /// was set from (the increment chart R_b ← exp([δω_b]×) R_b; feature: R_pᵀ R_b − I per bone
  /// b ≥ 1), for the adjoint (the held pose blend is a function of q_n). Tangent: δP_j of
  /// `nodes` (rows in their order) for δω (3 per bone). Cotangent: ADDS Σ_j (∂P_j/∂ω)ᵀ μ_j
  /// (μ: a 3-vector per listed node) into rotation_cotangent (3 per bone).
  void poseBlendTangent(const std::vector<Mat3>& R, const VecX& delta_omega,
                        const std::vector<int>& nodes, MatX3& dP) const;
  void poseBlendCotangent(const std::vector<Mat3>& R, const std::vector<int>& nodes,
                          const std::vector<Vec3>& mu, VecX& rotation_cotangent) const;
  /// poseBlendCotangent of the surface nodes for many pose blends at once: row k of
  /// `offsets_bar` (3#V, row-major: 3i + c) is a cotangent of the surface's offsets P_i held
  /// from the rotations R[k]; ADDS its rotation cotangent (3 per bone) into row k of
  /// `rotation_cotangents` (#rows × 3·#bones). One product with the surface's posedirs for all
  /// rows: it reads them once, not once per row.
  void surfacePoseBlendCotangents(const std::vector<std::vector<Mat3>>& R,
                                  const RowMatX& offsets_bar, RowMatX& rotation_cotangents) const;
  /// The surface's offsets P_i for many pose blends: row k (3#V, row-major) held from the
  /// rotations R[k]. One product with the surface's posedirs for all rows.
  RowMatX surfacePoseBlends(const std::vector<std::vector<Mat3>>& R) const;
  /// t_b − R_b J_b per bone: x_j = Σ_b w_jb (R_b Y_j + shift_b).
  void boneShifts(const std::vector<Mat3>& R, const MatX3& t, Vec3* shift) const;
  /// x_j = Σ_b w_jb (R_b Y + shift_b) for node j's unposed position Y (shift: boneShifts'), and
  /// M_j = Σ_b w_jb R_b when M is not null.
  Vec3 skin(int j, const std::vector<Mat3>& R, const Vec3* shift, const Vec3& Y,
            Mat3* M = nullptr) const;
  /// ‖posedirs rows of surface node i‖_F: ‖P_i‖ ≤ blendBound(i) · poseFeatureNorm().
  double blendBound(int i) const { return blend_bound_[i]; }
  double poseFeatureNorm() const { return feature_.norm(); }

  // ---- positions ----
  /// World positions x (#N × 3) of every node for bones and a soft state.
  void positions(const BoneFrames& bones, const VecX& state, MatX3& x) const;
  /// x rows of `nodes` (distinct; split over the threads from 512) for bones and a state.
  void positionsOf(const std::vector<int>& nodes, const BoneFrames& bones, const VecX& state,
                   MatX3& x) const;
  /// Skins the evaluated nodes at the current state (bones + u); cached by `version`.
  void prepare(long version, const BoneFrames& bones) const override;
  /// The ROM: the frames alone, the mass nodes' skinning deferred to ensurePrepared() or the
  /// next prepare() (their x, Y and M rows are stale until then); the FEM: prepare().
  void prepareFrames(long version, const BoneFrames& bones) const override;
  /// Skins what prepare() would at the frames set last (nothing when already done).
  void ensurePrepared() const;
  /// Skins `nodes` (distinct) at the prepared state: x, Y and M rows (the ROM's contact and
  /// output nodes; the FEM's prepare() skins every node).
  void skinNodes(const std::vector<int>& nodes) const;
  /// Positions x, unposed nodes Y and M_j of the nodes skinned at the prepared state.
  const MatX3& x() const { return x_; }
  const MatX3& Y() const { return Y_; }
  const Mat3& M(int j) const { return node_M_[j]; }
  const std::vector<Mat3>& R() const { return *cur_R_; }
  const MatX3& t() const { return *cur_t_; }
  /// Changes whenever the unposed positions Y of the skinned nodes may have (the soft state or
  /// the held pose blend changed), not with the bones: HeldMassMoments' key.
  long unposedStamp() const {
    refreshUnposed();
    return y_current_;
  }
  const std::vector<int>& surfaceNodes() const { return surface_nodes_; }
  /// World positions and unposed nodes of every surface node (#V × 3) at the prepared state.
  void surface(MatX3* x, MatX3* Y) const override;
  /// d(surface nodes)/dq rows (3#V × numDofs) as triplets.
  void surfaceJacobian(std::vector<Triplet>& triplets) const override;
  /// Node j (skinned at the prepared state) as a SkinnedPoint (sim/terms/term_blocks.h: its
  /// bones' weights and lever arms, and its soft DoFs' blocks; id set by the caller), for the
  /// node terms' parameter blocks.
  void point(int j, SkinnedPoint& p) const;
  /// μ_j = J_j λ (J_j = ∂x_j/∂q of point(j)) of every mass node, in setMassNodes' order: one
  /// pass per λ and skinning (split over the threads from 512 nodes), which the node terms'
  /// products with the same λ then share (inertia: parameters, node offsets, previous states;
  /// gravity: parameters) instead of each forming every μ_j again.
  const std::vector<Vec3>& massCotangents(const VecX& lambda) const;
  const std::vector<int>& massNodes() const { return mass_nodes_; }
  void surfacePoint(int i, SkinnedPoint& p, bool soft_blocks = true) const override {
    fillPoint(i, *cur_R_, Y_.row(i).transpose(), node_M_[i], p, soft_blocks);
  }
  void surfaceForces(const MatX3& forces, VecX& g) const override;
  /// Node j as a SkinnedPoint at other bones and soft state (e.g. q_n or q_{n−1}, for the
  /// inertia's prediction x̂), with the held pose blend: lever arms R_b (Y_j − J_b) with
  /// Y_j = X̄_j + P_j + u_j(state), soft blocks from Σ_b w_jb R_b of these bones.
  void pointAt(int j, const std::vector<Mat3>& R, const VecX& state, SkinnedPoint& p) const;
  /// M_j = Σ_b w_jb R_b (= ∂x_j/∂Y_j) for the given rotations.
  Mat3 blendMatrix(int j, const std::vector<Mat3>& R) const {
    Mat3 M = Mat3::Zero();
    for (int k = influence_start_[j]; k < influence_start_[j + 1]; ++k)
      M += influences_[k].weight * R[influences_[k].bone];
    return M;
  }

  // ---- the chain rule to q (at the prepared state) ----
  /// Adds Σ_j J_jᵀ f_j (f: per-node ∂E/∂x_j for the listed nodes) into g.
  void mapForces(const std::vector<int>& nodes, const std::vector<Vec3>& forces, VecX& g,
                 int offset) const;
  /// Appends Σ_j J_jᵀ K_j J_j (K_j symmetric 3 × 3; null = none) plus, when `forces` is given,
  /// the curvature of the rotating points against f_j: exact (psd = false) or, for psd, the PSD
  /// projection of each bone's rotation curvature (the mixed δω–δu terms dropped).
  /// `fixed` (FEM, nodes = the mass nodes only; may be null): the bone–tissue coupling and
  /// node-diagonal blocks go into it, laid out as couplingPositions(), instead of into H.
  /// `list`: the ROM value list and the scratch to use (0: inertia, 1: the potential terms).
  /// `K_scalar` (instead of K, which is then null): K_j = K_scalar[idx] · I (inertia).
  /// `soft_soft` false leaves out the soft–soft blocks M_jᵀ K_j M_j (a caller that adds a
  /// constant in their place: NodalInertiaTerm's approximate form).
  void mapHessian(const std::vector<int>& nodes, const std::vector<Mat3>* K,
                  const std::vector<Vec3>* forces, std::vector<Triplet>& H, int offset, bool psd,
                  int list, std::vector<Mat3>* fixed = nullptr,
                  const std::vector<double>* K_scalar = nullptr, bool soft_soft = true) const;
  /// g(u_j) += v (FEM: into u_j's entries; ROM: through φ into z).
  void addSoftGradient(VecX& g, int offset, int j, const Vec3& v) const;
  /// H(u_j, u_j) += B (symmetric). FEM: a triplet block; ROM: into value list `list`.
  void addSoftSoft(std::vector<Triplet>& H, int offset, int j, const Mat3& B, int list) const;
  /// FEM: the fixed positions (relative to the simulable's first DoF) of the blocks mapHessian
  /// writes for the mass nodes: per mass node with a DoF, from couplingStart(idx), four per
  /// influence a of bone b — (6b, u), (6b + 3, u), (u, 6b), (u, 6b + 3) — then (u, u).
  const std::vector<std::pair<int, int>>& couplingPositions() const { return coupling_dofs_; }

  // ---- the ROM's Hessian value lists ----
  /// The summed blocks of value list `list` (0: dynamic, 1: potential), at fixed positions:
  /// z–z blocks of group pairs (zzSlot(g, k): the upper ones g ≤ k are summed, the lower
  /// mirrored), then bone–z blocks (bzSlot(r, g), r = 2b for bone b's t rows, 2b + 1 for its ω
  /// rows), then their transposes (mirrored). Groups: numGroups().
  Mat3* reducedValues(int list) const { return reduced_values_[size_t(list)].data(); }
  int zzSlot(int h, int k) const { return zz_slot_[size_t(h) * size_t(num_groups_) + size_t(k)]; }
  int bzSlot(int r, int h) const { return bz_slot_[size_t(r) * size_t(num_groups_) + size_t(h)]; }
  /// Zeroes a list (no-op for the FEM).
  void beginList(int list) const override;
  /// After the terms of one evaluation: appends list `list`'s blocks to H as triplets or, with
  /// `blocks`, returns the list as fixed blocks (valid until the next beginList of that list).
  /// No-op for the FEM.
  void flushList(int list, std::vector<Triplet>& H, int offset,
                 std::vector<FixedHessianBlocks>* blocks) const override;
  /// Completes a list after its terms: the bones' dense mode rows into their bone–z slots,
  /// then the lower z–z and z–bone blocks from the summed ones.
  void mirrorReduced(int list) const;
  /// Marks both lists mirrored (reducedHessians mirrors them on two threads).
  void setMirrored(bool on) const { mirrored_[0] = mirrored_[1] = on; }

 private:
  Vec3 blendOf(int j) const;
  /// p from node j's influences, rotations R, unposed position Y and M_j = Σ_b w_jb R_b.
  void fillPoint(int j, const std::vector<Mat3>& R, const Vec3& Y, const Mat3& M, SkinnedPoint& p,
                 bool soft_blocks = true) const;
  template <int Rows>
  void addBoneSoft(std::vector<Triplet>& H, int offset, int row, int j,
                   const Eigen::Matrix<double, Rows, 3>& B, int list) const;

  int num_bones_ = 0, num_surface_ = 0, bone_dofs_ = 0;
  bool reduced_ = false;
  MatX3 rest_;                      // #N × 3, X̄(β)
  const MatX* posedirs_ = nullptr;  // 3#N × 207 (owned by the avatar's template)
  std::vector<int> parents_;
  MatX3 joints_;  // 24 × 3
  // Pose blend: the feature (9 · 23) of the held pose; FEM: every node's offsets in blend_.
  // ROM: blend_ row j is current when blend_stamp_[j] == pose_stamp_, else blendOf evaluates it
  // from posedirs_T_ (each node's 207 × 3 block contiguous, for the nodes with a slot: the
  // surface and the mass nodes), else from posedirs.
  VecX feature_;
  bool from_feature_ = true;  // ROM: blend_ follows feature_ (not setPoseBlendOffsets')
  std::vector<Mat3> held_R_;  // ROM: the rotations feature_ comes from
  /// The pose feature of rotations R (9 per bone but the root: R_pᵀ R_b − I).
  void featureOf(const std::vector<Mat3>& R, VecX& feature) const;
  /// ADDS to rotation_cotangent (3 per bone) the rotations' cotangent for a cotangent of the
  /// feature of R (featureOf).
  template <class Feature, class Out>
  void addFeatureCotangent(const std::vector<Mat3>& R, const Feature& feature_bar,
                           Out&& rotation_cotangent) const;
  /// Whether more than an eighth of all nodes in `nodes` have no contiguous posedirs rows (the
  /// pose blend's tangent and cotangent then go through the whole matrix at once).
  bool manyUnslotted(const std::vector<int>& nodes) const;
  mutable MatX3 blend_;  // #N × 3
  int pose_stamp_ = 0;
  long blend_epoch_ = 0;  // counts the changes of the held pose blend (for Y_'s rows)
  mutable std::vector<int> blend_stamp_;
  MatX posedirs_T_;
  std::vector<int> blend_slot_;
  VecX blend_bound_;  // #V
  // Per bone: the largest blend_bound_ and displacementWeight of its dominated surface nodes.
  std::vector<double> bone_blend_bound_, bone_weight_bound_, bone_mode_bound_;
  VecX phi_sum_;    // #V (ROM): Σ_h φ_h(i)
  VecX mode_norm_;  // #V (ROM with modes): ‖Ψ_i‖_F
  VecXi state_nodes_;
  std::vector<int> node_dof_;  // FEM layout: 3 · (rank among soft nodes), −1 on bone nodes
  // ROM: u_j = Σ φ z_h over phi_[phi_start_[j] .. phi_start_[j + 1]) as (handle, φ); the
  // handle's z offset (3h) at a handle node, −1 elsewhere.
  std::vector<int> phi_start_;
  std::vector<std::pair<int, double>> phi_;
  std::vector<int> state_dof_;
  int num_handles_ = 0, num_modes_ = 0, num_groups_ = 0;
  // ROM with modes: Ψ (3#N × r, row-major: node j's 3 × r block contiguous).
  RowMatX modes_;
  std::vector<int> influence_start_;
  std::vector<Influence> influences_;
  std::vector<int> eval_nodes_, all_nodes_, surface_nodes_;
  std::vector<int> mass_nodes_;  // setMassNodes'
  // FEM: see couplingPositions(); per mass node idx its blocks start at coupling_start_[idx].
  std::vector<std::pair<int, int>> coupling_dofs_;
  std::vector<int> coupling_start_;

  // Caches of the prepared state.
  mutable long version_ = -1, pending_version_ = -1;  // skinned at; frames set at
  /// Starts a new unposed stamp (y_current_) when the soft state or the held pose blend changed
  /// since the last one.
  void refreshUnposed() const;
  mutable MatX3 x_, Y_;
  // Y_ row j is current when y_stamp_[j] == y_current_, which changes with the soft state
  // (y_state_: the one it was skinned at) and the held pose blend (y_epoch_).
  mutable std::vector<long> y_stamp_;
  mutable long y_current_ = 0, y_epoch_ = -1;  // y_epoch_ −1: nothing skinned yet
  mutable VecX y_state_;
  mutable std::vector<Mat3> node_M_;  // M_j = Σ_b w_jb R_b
  mutable const std::vector<Mat3>* cur_R_ = nullptr;
  mutable const MatX3* cur_t_ = nullptr;
  mutable long skinnings_ = 0;  // skinNodes calls: x, Y and M rows may have changed
  // massCotangents' μ_j, for the λ and skinning (skinnings_) they were formed at (−1: none).
  mutable std::vector<Vec3> mass_mu_;
  mutable VecX mass_mu_lambda_;
  mutable long mass_mu_skinning_ = -1;
  mutable BonePairBlocks pair_blocks_[2];  // mapHessian's, per value list
  // mapHessian with K_j = κ_j I: per ordered bone pair (b, c) (key b · #bones + c), Σ κ w_b w_c
  // (s), its sums weighted by r_c (p) and r_b (q), and Σ κ w_b w_c r_c r_bᵀ (W); per value list.
  struct PairMoments {
    double s = 0.0;
    Vec3 p = Vec3::Zero(), q = Vec3::Zero();
    Mat3 W = Mat3::Zero();
    PairMoments& operator+=(const PairMoments& o) {
      s += o.s;
      p += o.p;
      q += o.q;
      W += o.W;
      return *this;
    }
  };
  mutable TouchedValues<PairMoments> pair_moments_[2];
  mutable TouchedValues<PairMoments> pair_moments_second_;  // mapHessian's second half (FEM)
  // ROM Hessian blocks at fixed positions (buildReducedPattern): z–z blocks (zz_slot_[h · H +
  // k], H handles), bone–z blocks (bz_slot_[r · H + h]), then the bone–z blocks' transposes;
  // positions relative to the first DoF. Two value lists: 0 (inertia), 1 (the potential terms).
  std::vector<int> zz_slot_, bz_slot_;
  int num_zz_ = 0, num_bz_ = 0;
  std::vector<std::pair<int, int>> zz_mirror_;  // (slot of (h, k), slot of (k, h)) for h > k
  std::vector<std::pair<int, int>> reduced_positions_;
  mutable std::vector<Mat3> reduced_values_[2];
  mutable bool mirrored_[2] = {false, false};  // the lower blocks are current
  // ROM with modes, per list: Σ B Ψ_j of addBoneSoft per bone (6 rows per bone: t, then ω), and
  // which bones have any; mirrorReduced folds them into the bone–z slots.
  mutable RowMatX bone_modes_[2];
  mutable std::vector<char> bone_modes_touched_[2];
};

}  // namespace flsh::detail
