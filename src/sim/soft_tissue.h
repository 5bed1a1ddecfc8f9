// The soft tissue of the FEM and ROM soft skeletons (ARCHITECTURE.md §4), private to Simulable:
// a kinematics (soft/soft_kinematics.h: the tet nodes' skinning, the soft state's layout, the
// chain rule) and the node terms that read it, one file pair each under soft/: nodal inertia,
// nodal gravity, elasticity (FEM, or the ROM's in the subspace with its cubature) and collider
// contact on the surface nodes. The bones' own terms (joint and tracking springs) stay with
// Simulable. This class builds the parts for one avatar and runs them as Simulable asks: one
// term at a time, or, for the ROM, the terms of one evaluation spread over two threads.
#pragma once

#include <functional>
#include <memory>
#include <vector>

#include "flsh/contact/collider.h"
#include "flsh/contact/contact_energy.h"
#include "flsh/core/types.h"
#include "flsh/volume/soft_avatar.h"
#include "sim/soft/elastic_elements.h"
#include "sim/soft/material_chain.h"
#include "sim/soft/modal_elasticity_term.h"
#include "sim/soft/nodal_gravity_term.h"
#include "sim/soft/nodal_inertia_term.h"
#include "sim/soft/node_contact_term.h"
#include "sim/soft/node_masses.h"
#include "sim/soft/reduced_elasticity_term.h"
#include "sim/soft/shape_chain.h"
#include "sim/soft/soft_kinematics.h"
#include "sim/two_thread_schedule.h"

namespace flsh::detail {

class SoftTissue final : public TwoThreadSchedule {
  // Declared (so constructed) before the state references u, u_n, u_nm1 that bind to its
  // members: referring to a member of an object before its constructor runs is undefined.
  SoftKinematics kin_;

 public:
  /// Reads the avatar's volumetric data (soft tissue on, initialized). `joints`: 24 × 3 rest
  /// joints J(β) (the simulable's).
  SoftTissue(const SoftAvatar& avatar, const MatX3& joints, const std::vector<int>& parents,
             double time_step);
  SoftTissue(const SoftTissue&) = delete;
  SoftTissue& operator=(const SoftTissue&) = delete;

  const SoftKinematics& kinematics() const { return kin_; }
  /// The node terms (inertia, gravity, elasticity, contact), for Simulable::energyTerms.
  std::vector<const EnergyTerm*> terms() const;
  /// The node terms of the dynamic part (inertia) and of the potential part (elasticity,
  /// gravity, contact: the FEM's fixed block lists come in this order, the elastic node pairs
  /// then gravity's coupling blocks) with their block forms, and the value lists they sum into.
  std::vector<TermEntry> dynamicTerms() const { return {{inertia_.get(), inertia_.get()}}; }
  std::vector<TermEntry> potentialTerms() const {
    return {{elastic_.get(), elastic_.get()},
            {gravity_.get(), gravity_.get()},
            {contact_.get(), contact_.get()}};
  }
  const HessianValueLists& valueLists() const { return kin_; }

  int numNodes() const { return kin_.numNodes(); }
  int numSurface() const { return kin_.numSurface(); }
  bool reduced() const { return kin_.reduced(); }
  int numSoftDofs() const { return kin_.numSoftDofs(); }
  /// The node of each 3-value block of the soft state: the soft-tissue nodes (FEM) or the handles
  /// (ROM, where u at a handle is its z_h: φ_h = 1 there and every other φ is 0).
  const VecXi& softNodes() const { return kin_.softNodes(); }
  /// Offset in the soft state of the 3 values that are node j's displacement, −1 when u_j is not
  /// a state entry of its own (bone nodes; in the ROM every node but the handles).
  int nodeDof(int j) const { return kin_.nodeDof(j); }
  Vec3 displacementOf(const VecX& state, int j) const { return kin_.nodeDisplacement(state, j); }
  void displacementBasis(int j, std::vector<std::pair<int, Mat3>>& out) const {
    kin_.displacementBasis(j, out);
  }

  // ---- state (the bones live in Simulable; the soft state in the kinematics) ----
  VecX &u, &u_n, &u_nm1;

  void setPoseBlend(const std::vector<Mat3>& R) { kin_.setPoseBlend(R); }
  const MatX3& poseBlend() const { return kin_.poseBlend(); }
  void setPoseBlendOffsets(const MatX3& offsets) { kin_.setPoseBlendOffsets(offsets); }
  /// ROM: the rotations the held pose blend was set from (null for the FEM and after offsets).
  const std::vector<Mat3>* heldPoseRotations() const { return kin_.heldPoseRotations(); }
  void evaluatedPoseBlend(std::vector<int>& nodes, MatX3& offsets) const {
    kin_.evaluatedPoseBlend(nodes, offsets);
  }
  void seedPoseBlend(const std::vector<int>& nodes, const MatX3& offsets) {
    kin_.seedPoseBlend(nodes, offsets);
  }
  void positions(const BoneFrames& bones, const VecX& state, MatX3& x) const {
    kin_.positions(bones, state, x);
  }
  /// x̂ = 2 x(q_n) − x(q_{n−1}) with the held pose blend (it carries no momentum).
  void setPrediction(const BoneFrames& bones_n, const BoneFrames& bones_nm1) {
    inertia_->setPrediction(bones_n, bones_nm1);
  }
  /// Skins the nodes the terms read at the current state (bones + u); cached by `version`.
  void prepare(long version, const BoneFrames& bones) const { kin_.prepare(version, bones); }
  /// Node positions of the prepared state: every node in the FEM; in the ROM only the mass
  /// nodes (surface() for the surface, positions() for every node).
  const MatX3& currentPositions() const { return kin_.x(); }

  // ---- at the prepared state (the node terms themselves: terms(), dynamicTerms(),
  // potentialTerms()) ----
  /// The ROM's two-thread schedule (TwoThreadSchedule; throws for the FEM): reducedGradient,
  /// reducedHessians with contact at c.contact's candidates (skinned first) beside inertia.
  double gradient(const TermContext& c, VecX& g, int offset) const override;
  void hessians(const TermContext& c, std::vector<Triplet>& H_dynamic,
                std::vector<Triplet>& H_potential, int offset, bool psd) const override;
  /// ROM with modes and the rest-stiffness split: hessians' exact form with a constant soft–soft
  /// block K_r + C (the split's exact rest stiffness and NodalInertiaTerm::constantSoftBlock) in
  /// place of the elastic tets' and inertia's soft–soft blocks; contact, gravity, the bones and
  /// their coupling to the soft state stay exact. False (nothing evaluated) without the split.
  bool approximateHessians(const TermContext& c, std::vector<Triplet>& H_dynamic,
                           std::vector<Triplet>& H_potential, int offset) const override;
  /// Bases with modes only: the handle basis' exact Hessian is cheap (sparse φ), and factoring
  /// its 405 DoFs at every iteration cost more than the PCG iterations on the lagged factor
  /// (rom_benchmark 300, walk: 39–57 against 83–109 steps/s).
  bool hasApproximateHessians() const override {
    return reduced_elastic_ && reduced_elastic_->hasRestSplit() && kin_.numModes() > 0;
  }
  /// ROM: inertia's, gravity's and the elastic term's gradients, and `potential_first`'s
  /// (e.g. contact, on nodes skinned before, with skin = false), added into g on two threads:
  /// inertia and gravity (one mapping of their summed node forces) with the first elastic tets
  /// into g, beside potential_first and the other tets into a scratch vector of g's size (added
  /// into g after). Returns the energy of inertia, gravity and the elastic term (not
  /// potential_first's), which the same passes give.
  double reducedGradient(const Vec3& gravity, VecX& g, int offset,
                         const std::function<void(VecX&)>& potential_first) const;
  /// ROM: both Hessian parts' node and tet terms on two threads (Simulable::
  /// getHessianTripletVector): inertia (value list 0, bone triplets into H_dynamic) beside
  /// `potential_first` (may be empty: e.g. contact, on nodes skinned before, with skin = false),
  /// then gravity, the elastic tets and the exact rest-stiffness term (list 1, bone triplets
  /// into H_potential); a share of inertia's mass nodes is mapped on the second thread too
  /// (into list 1 and H_potential), to balance the two. Both lists come back mirrored
  /// (flushList then only hands them over).
  /// hessians (approximate false) and approximateHessians: contact's candidates skinned, then
  /// reducedHessians with contact beside inertia.
  void scheduledHessians(const TermContext& c, std::vector<Triplet>& H_dynamic,
                         std::vector<Triplet>& H_potential, int offset, bool psd,
                         bool approximate) const;
  /// Adds the upper group blocks of a soft–soft matrix (numSoftDofs²) into a value list.
  void addConstantSoftBlock(const MatX& C, Mat3* values) const;
  /// `approximate`: approximateHessians' form (exact, psd false, with the constant block).
  void reducedHessians(const Vec3& gravity, std::vector<Triplet>& H_dynamic,
                       std::vector<Triplet>& H_potential, int offset, bool psd,
                       const std::function<void()>& potential_first,
                       bool approximate = false) const;

  // ---- the held pose blend's share of the previous-state derivatives (the adjoint) ----
  // P = P(R_n) moves every node term's gradient through Y (node_offset_derivatives.h: inertia,
  // with its prediction, gravity and contact), chained to q_n's rotation increments by the
  // kinematics (poseBlendTangent / poseBlendCotangent). The inertia's own dependence on q_n and
  // q_{n−1} through x̂ is the term's (EnergyTerm::addPreviousStatesProducts).
  /// ADDS (∂g/∂ω_n)ᵀ λ into a_n's rotation rows (λ, a_n: the simulable's own DoFs).
  /// `version`: the simulable's state version (nodeOffsetCotangent's cache).
  void addPoseBlendProducts(const TermContext& c, const VecX& lambda, VecX& a_n,
                            long version) const;
  /// ADDS ∂g/∂ω_n δω_n (δω_n: dq_n's rotation entries) into out.
  void addPoseBlendTangent(const TermContext& c, const VecX& dq_n, VecX& out) const;
  /// The chain itself: ADDS into a_n's rotation rows the cotangent of q_n's rotation increments
  /// for a cotangent of the held offsets P (`offsets`: rows for nodes 0..rows − 1, zero rows
  /// skipped), the pose blend held from the rotations R_n.
  void addPoseBlendCotangent(const std::vector<Mat3>& R_n, const MatX3& offsets, VecX& a_n) const;

  // ---- Shape (β) beyond the node terms' own blocks (the masses' and the contact areas'
  // ∂/∂β: inertia, gravity, contact) — the rest nodes through every node term's Y
  // (node_offset_derivatives.h) and the elastic term's rest shapes and materials
  // (ElasticityTerm::addShapeProducts) ----
  /// ADDS λᵀ ∂g/∂β into beta_bar (K); `summed`: without the elastic term's share, which a
  /// sweep takes from its sums (ElasticityTerm::accumulateMaterialProducts with the shape, then
  /// addAccumulatedMaterialProducts).
  void addShapeProducts(const TermContext& c, const VecX& lambda, VecX& beta_bar, long version,
                        bool summed = false) const;
  /// ADDS ∂g/∂β dβ into out / ∂g/∂β into J (numDofs × K).
  void addShapeTangent(const TermContext& c, const VecX& dbeta, VecX& out) const;
  void addShapeJacobian(const TermContext& c, MatX& J) const;
  /// ADDS Σ_i (∂X̄_i/∂β)ᵀ Y_bar_i into beta_bar for a cotangent of the first nodes' Y (rows).
  void addRestNodesCotangent(const MatX3& Y_bar, VecX& beta_bar) const {
    shape_chain_.addNodeCotangent(Y_bar, beta_bar);
  }

  /// The contact broad phase's margins (SoftKinematics::contactMargins) from the surface nodes
  /// each bone dominates.
  void setContactBones(const std::vector<std::vector<int>>& dominated) {
    kin_.setContactBones(dominated);
  }
  /// New rest joints (Simulable::setParameter(RestJoints)); call setPrediction after.
  void setJoints(const MatX3& joints) { kin_.setJoints(joints); }
  /// ROM: elastic samples in the bounded branch of the rest split at the current state.
  int restSplitBoundedSamples() const {
    return reduced_elastic_ ? reduced_elastic_->boundedSamples() : 0;
  }
  /// The elastic term (its Material products split for the reverse sweep).
  const ElasticityTerm& elasticTerm() const { return *elastic_; }
  /// β's chain (rest nodes, materials, masses).
  const ShapeChain& shapeChain() const { return shape_chain_; }
  /// The Material group's chain (coefficient values ↔ the material file's parameters).
  const MaterialChain& materialChain() const { return material_chain_; }
  /// The node contact term, as the broad phase asks it (refresh).
  const ContactTerm& contactTerm() const { return *contact_; }
  /// World positions and unposed nodes of every surface node (#V × 3) at the prepared state.
  void surface(MatX3* x, MatX3* Y) const { kin_.surface(x, Y); }
  /// d(surface nodes)/dq rows (3#V × numDofs) as triplets.
  void surfaceJacobian(std::vector<Triplet>& triplets) const { kin_.surfaceJacobian(triplets); }

 private:
  std::vector<const NodeOffsetDerivatives*> nodeOffsetTerms() const {
    return {inertia_.get(), gravity_.get(), contact_.get()};
  }
  NodeMasses masses_;
  HeldMassMoments held_moments_;  // the inertia's and gravity's bone rows in the presolve
  MaterialChain material_chain_;
  ShapeChain shape_chain_;
  std::unique_ptr<NodalInertiaTerm> inertia_;
  std::unique_ptr<NodalGravityTerm> gravity_;
  std::unique_ptr<ElasticityTerm> elastic_;
  const ReducedElasticity* reduced_elastic_ = nullptr;  // elastic_ in the ROM
  std::unique_ptr<NodeContactTerm> contact_;
  /// Σ over the node terms of (∂g/∂Y)ᵀ λ (#N × 3): what the pose blend's and β's rest nodes'
  /// chains both read. Kept for the last (state version, λ): a reverse sweep asks for it twice
  /// per step (previous states, then parameters).
  const MatX3& nodeOffsetCotangent(const TermContext& c, const VecX& lambda, long version) const;
  /// ADDS Σ over the node terms of ∂g/∂Y dY into out (dY: #N × 3).
  void addNodeOffsetTangent(const TermContext& c, const MatX3& dY, VecX& out) const;
  mutable long offset_version_ = -1;
  mutable VecX offset_lambda_;
  mutable MatX3 offset_cotangent_;
  mutable std::vector<Vec3> forces_;
  mutable VecX gradient_scratch_;
};

}  // namespace flsh::detail
